"""The ``sepfm_ros`` console command: one subcommand per package executable.

``sepfm_ros NAME ARGS`` runs exactly what ``ros2 run sepfm_ros NAME ARGS`` runs after
``colcon build``; ``python -m sepfm_ros`` is the same command. Each subcommand lives in its own
module and is imported only when asked for, so ``sepfm_ros --help`` works without ROS installed.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Sequence

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
    func: Callable[[list[str]], int | None] = getattr(
        importlib.import_module(module_name), func_name
    )
    code = func(list(argv))
    return int(code or 0)


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
