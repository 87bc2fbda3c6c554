"""The ``sepfm_ros`` console command: one subcommand per package executable.

``sepfm_ros NAME ARGS`` runs exactly what ``ros2 run sepfm_ros NAME ARGS`` runs after
``colcon build``; ``python -m sepfm_ros`` is the same command. Each subcommand lives in its own
module and is imported only when asked for, so ``sepfm_ros --help`` works without ROS installed.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

# name -> (module, function, one-line help). The function takes argv (list of str) and returns
# a process exit code.
SUBCOMMANDS: dict[str, tuple[str, str, str]] = {
    "demo": ("sepfm_ros.demo", "main", "run the main job on data the package ships or makes"),
    "node": ("sepfm_ros.ros.commands.node", "main", "the live two-view geometry node"),
    "make_bag": (
        "sepfm_ros.ros.commands.make_bag",
        "main",
        "build a bag from images or shared data",
    ),
    "replay": ("sepfm_ros.ros.commands.replay", "main", "publish a bag into live topics"),
    "record": ("sepfm_ros.ros.commands.record", "main", "record topics into a bag"),
    "process": ("sepfm_ros.ros.commands.process", "main", "run the pipeline over a bag offline"),
    "eval": ("sepfm_ros.evaluation.cli", "main", "evaluate estimators on pairs with ground truth"),
    "calibration_check": (
        "sepfm_ros.ros.commands.calibration_check",
        "main",
        "check a stereo calibration",
    ),
    "rectify": (
        "sepfm_ros.ros.commands.rectify",
        "main",
        "rectified stereo images without camera_info",
    ),
    "audit": (
        "sepfm_ros.ros.commands.audit",
        "main",
        "audit many rigs' calibration over many bags",
    ),
    "warm_up": (
        "sepfm_ros.warm_up",
        "main",
        "compile (or load) the kernels before the first start",
    ),
}


def _usage() -> str:
    width = max(len(n) for n in SUBCOMMANDS)
    lines = ["usage: sepfm_ros COMMAND [ARGS...]", "", "commands:"]
    lines += [f"  {n.ljust(width)}  {h}" for n, (_, _, h) in SUBCOMMANDS.items()]
    lines += ["", "`sepfm_ros COMMAND --help` describes a command."]
    return "\n".join(lines)


def run(name: str, argv: Sequence[str]) -> int:
    """Run subcommand ``name`` with arguments ``argv``; return its exit code."""
    if name not in SUBCOMMANDS:
        print(f"sepfm_ros: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, func_name, _ = SUBCOMMANDS[name]
    try:
        func: Callable[[list[str]], int | None] = getattr(
            importlib.import_module(module_name), func_name
        )
        code = func(list(argv))
    except ImportError as e:  # not installed, or only the source folder (a namespace package)
        if e.name is None or e.name.split(".")[0] != "sepfm_msgs":
            raise
        # one line naming the fix, no traceback: a plain `colcon build` skips the nested package
        print(f"sepfm_ros: {_missing_msgs()}", file=sys.stderr)
        return 1
    return int(code or 0)


def _ament_prefix() -> Path | None:
    """The ament prefix this package is installed in (colcon), or None (pip)."""
    marker = Path("share", "ament_index", "resource_index", "packages", "sepfm_ros")
    here = Path(__file__).absolute()
    prefixes = list(here.parents)  # a colcon install: <prefix>/lib/pythonX.Y/site-packages/...
    # a colcon --symlink-install runs the sources: its prefix is on AMENT_PREFIX_PATH
    prefixes += [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return next((p for p in prefixes if (p / marker).is_file()), None)


def _missing_msgs() -> str:
    """Why sepfm_msgs cannot be imported here and what fixes it, as one sentence."""
    not_built = "the interface package sepfm_msgs is not built"
    prefix = _ament_prefix()
    if prefix is None:  # pip: the folder beside the package in a clone
        folder = Path(__file__).resolve().parent.parent / "sepfm_msgs"
        where = folder if (folder / "package.xml").is_file() else "./sepfm_msgs"
        return f"{not_built}: run `pip install {where}` (README)"
    # colcon's isolated layout (<ws>/install/<package>) or a merged one (<ws>/install)
    install = prefix.parent if (prefix.parent / "setup.sh").is_file() else prefix
    workspace = install.parent
    if (install / "sepfm_msgs").is_dir() or (install / "share" / "sepfm_msgs").is_dir():
        return (
            f"the interface package sepfm_msgs is built in {install}: source its setup.bash again"
        )
    nested = _nested_msgs_folder(workspace) or Path("src", "sepfm_ros", "sepfm_msgs")
    base = nested.parts[0] if nested.parts[0] == "src" else "."
    return (
        f"{not_built} (colcon does not look inside a package's folder): run "
        f"`colcon build --base-paths {base} {nested}` in {workspace}, then source "
        "install/setup.bash again"
    )


def _nested_msgs_folder(workspace: Path) -> Path | None:
    """sepfm_msgs's folder inside a package folder of ``workspace``, relative to it."""
    seen: set[str] = set()
    for folder, dirs, files in os.walk(workspace, followlinks=True):  # as colcon crawls
        here = Path(folder)
        if os.path.realpath(folder) in seen or "COLCON_IGNORE" in files:
            dirs[:] = []
        elif "package.xml" in files:  # colcon stops here; so does this search
            dirs[:] = []
            if (here / "sepfm_msgs" / "package.xml").is_file():
                return here.relative_to(workspace) / "sepfm_msgs"
        else:
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        seen.add(os.path.realpath(folder))
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``sepfm_ros`` and ``python -m sepfm_ros``."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0 if args else 2
    return run(args[0], args[1:])


def _entry(name: str) -> Callable[[], int]:
    def entry() -> int:
        return run(name, sys.argv[1:])

    entry.__name__ = f"{name}_main"
    return entry


# Console-script entry points for `ros2 run sepfm_ros NAME` (see setup.py).
node_main = _entry("node")
make_bag_main = _entry("make_bag")
replay_main = _entry("replay")
record_main = _entry("record")
process_main = _entry("process")
eval_main = _entry("eval")
warm_up_main = _entry("warm_up")
calibration_check_main = _entry("calibration_check")
rectify_main = _entry("rectify")
audit_main = _entry("audit")
