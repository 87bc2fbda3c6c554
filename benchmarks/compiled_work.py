"""Timing helpers of the estimator benchmarks: the untimed run before a method's timed runs on a
pair (:func:`warm_up`), and the compiled share of an estimate's time, how much of it runs inside
sepfm_ros's numba kernels and OpenCV's functions (measured with cProfile), set against the most
time over USAC_MAGSAC's a target allows."""

from __future__ import annotations

import cProfile
import pstats
import sys
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np
from numba.core.dispatcher import Dispatcher


def warm_up(run: Callable[..., Any], *args: Any) -> None:
    """``run(*args)`` once, untimed, before a method's timed runs on a pair: each method is then
    timed with its own code and the pair's data in the caches. Without it, the method timed
    first on a pair ran right after another library's runs on the previous pair (sep4 took
    2.19 ms after SupeRANSAC on the shared pairs at SIFT 0.75, 1.53 ms after itself)."""
    run(*args)


def compiled_functions() -> set[tuple[str, str]]:
    """(file, name) of every numba-compiled function of sepfm_ros: what cProfile records a call
    of a compiled kernel from Python under (kernels that call each other are one entry)."""
    keys = set()
    for name, module in list(sys.modules.items()):
        if name.startswith("sepfm_ros"):
            for value in vars(module).values():
                if isinstance(value, Dispatcher):
                    code = value.py_func.__code__
                    keys.add((code.co_filename, code.co_name))
    return keys


#: how cProfile names OpenCV's functions
CV2_FUNCTIONS = {f"<{name}>" for name in dir(cv2)}


def compiled_share(run: Callable[[], object]) -> float:
    """Share of ``run()``'s time, under cProfile, spent inside compiled code: sepfm_ros's numba
    kernels and OpenCV's functions (the rest is Python and numpy's Python-level calls). The
    profiler slows Python calls far more than a compiled call, so the share is a lower bound of
    the unprofiled one."""
    profile = cProfile.Profile()
    profile.enable()
    run()
    profile.disable()
    stats = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    kernels = compiled_functions()
    total = compiled = 0.0
    for (path, _, name), row in stats.items():
        total += row[2]  # time inside the function itself
        if (path, name) in kernels or (path == "~" and name in CV2_FUNCTIONS):
            compiled += row[2]
    return compiled / total if total > 0 else float("nan")


def compiled_note(
    compiled_ms: Sequence[float], measured_ms: Sequence[float], magsac_ms: float, required: float
) -> str:
    """The compiled work of the default method per pair (numba kernels and OpenCV: each pair's
    :func:`compiled_share` of its measured ms), and its measured ms per pair, against
    ``required`` times USAC_MAGSAC's median ms."""
    compiled = float(np.median(compiled_ms))
    measured = float(np.median(measured_ms))
    verdict = "above" if compiled > required * magsac_ms else "within"
    return (
        f"Compiled work (numba kernels and OpenCV, each pair's share of a profiled run times its "
        f"measured ms): median {compiled:.2f} ms per pair, {compiled / magsac_ms:.2f}x "
        f"USAC_MAGSAC's median; the method's median {measured:.2f} ms is "
        f"{measured / magsac_ms:.2f}x. Required: at most {required:.2f}x "
        f"({required * magsac_ms:.2f} ms); the compiled work alone is {verdict} it."
    )
