"""``sepfm_ros warm_up``: compile the numba kernels now, or load them, and say where they live.

The estimator and the matcher run numba kernels. The first process after an install (or after
a source change) compiles them, which takes 30-60 s; later processes load them from numba's
on-disk cache in about a second. Run this once after installing (``sepfm_ros warm_up``, or
``ros2 run sepfm_ros warm_up`` after ``colcon build``) so that the node's first start does not
wait for the compiler.

The cache lives beside the package sources (``__pycache__`` folders of the installed package,
writable in a colcon install or a virtual environment); numba falls back to the user's cache
folder (``~/.cache/numba``) when the package folder is read-only, and ``NUMBA_CACHE_DIR``
overrides both.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass


@dataclass(frozen=True)
class CacheReport:
    """What one warm-up did: kernels compiled (cache misses) and loaded (hits), and where.

    Counts are (kernel, signature) pairs. A cold start compiles the kernels a kernel calls as
    well; a warm start loads only the outer ones (their machine code includes the callees), so
    a cold count is larger than the warm one.
    """

    seconds: float
    compiled: int
    loaded: int
    cache_dirs: tuple[str, ...]


def package_dispatchers() -> list:
    """Every numba-compiled function defined in an imported ``sepfm_ros`` module."""
    from numba.core.dispatcher import Dispatcher

    found: dict[int, Dispatcher] = {}
    for name, module in list(sys.modules.items()):
        if name == "sepfm_ros" or name.startswith("sepfm_ros."):
            for value in list(vars(module).values()):
                if isinstance(value, Dispatcher):
                    found[id(value)] = value
    return list(found.values())


def warm_up_report() -> CacheReport:
    """Compile or load every kernel behind a frame pair and count which it was."""
    from sepfm_ros.pipeline.compiled import warm_up

    seconds = warm_up()
    dispatchers = package_dispatchers()
    # per kernel and signature: a miss means it was compiled (numba may look a signature up
    # more than once, so lookups are not counted)
    compiled = sum(len(d.stats.cache_misses) for d in dispatchers)
    loaded = sum(len(set(d.stats.cache_hits) - set(d.stats.cache_misses)) for d in dispatchers)
    dirs = tuple(sorted({str(d.stats.cache_path) for d in dispatchers if d.stats.cache_path}))
    return CacheReport(seconds, compiled, loaded, dirs)


def main(argv: list[str]) -> int:
    """Entry point of ``sepfm_ros warm_up``; prints what was compiled or loaded, and where."""
    p = argparse.ArgumentParser(
        prog="sepfm_ros warm_up",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.parse_args(argv)
    print("sepfm_ros warm_up: compiling or loading the numba kernels ...", flush=True)
    r = warm_up_report()
    if r.compiled:
        what = f"compiled {r.compiled} kernels and loaded {r.loaded} from the cache"
    else:
        what = f"loaded all {r.loaded} kernels from the cache (nothing to compile)"
    print(f"sepfm_ros warm_up: {what} in {r.seconds:.1f} s")
    for path in r.cache_dirs:
        print(f"  cache: {path}")
    return 0
