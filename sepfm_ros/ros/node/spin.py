"""The process around a long-running node (``sepfm_ros node``, ``sepfm_ros rectify``): its command
line takes ROS arguments only, and the node spins on a single-threaded executor until SIGINT or
SIGTERM."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import TypeVar

import cv2
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from threadpoolctl import threadpool_limits

N = TypeVar("N", bound=Node)


def own_arguments(prog: str, node_name: str, argv: list[str]) -> list[str]:
    """``argv`` without its ROS arguments (``--ros-args ...``); ROS arguments rcl cannot parse
    (a remap to a name with a space, ...) exit 2 with rcl's reason after ``prog``."""
    from rclpy.impl.implementation_singleton import rclpy_implementation
    from rclpy.utilities import remove_ros_args

    try:
        return list(remove_ros_args([node_name, *argv])[1:])
    except rclpy_implementation.RCLInvalidROSArgsError as err:
        reason = str(err).split(", at ")[0]  # rcl appends its source locations
        print(f"{prog}: invalid ROS arguments: {reason}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None


def parse_command_line(
    prog: str, node_name: str, argv: list[str], usage: str, help_text: str
) -> None:
    """Refuse ROS arguments rcl cannot parse (a remap rule with a space, ...) and any argument
    that is not a ROS argument (exit 2, with the reason or ``prog``'s usage); ``--help`` prints
    ``help_text`` and exits."""
    own = own_arguments(prog, node_name, argv)
    parser = argparse.ArgumentParser(
        prog=prog,
        usage=usage,
        description=help_text,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.parse_args(own)


def spin_until_shutdown(executor: Executor) -> None:
    """``executor.spin()`` until SIGINT or SIGTERM shuts its context down.

    rclpy's signal handler shuts the context down from another point in the program: when that
    happens after spin checked the context and before it built its wait set, building the wait
    set fails on the shut context (``RCLError``). An error raised once the context is shut is
    that shutdown and ends the spin quietly; one raised while the context is still up is
    re-raised.
    """
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if executor.context.ok():
            raise


def refusal(err: Exception) -> str:
    """Why a node could not start, for its user: the node's own ValueError (its parameter
    checks) or rclpy's refusal of a parameter (out of its range, of another type)."""
    if isinstance(err, ParameterException):
        return f"invalid parameters: {err}"
    return str(err)


def run_node(
    prog: str,
    node_name: str,
    argv: list[str],
    make_node: Callable[[], N],
    before_destroy: Callable[[N], None] | None = None,
) -> int:
    """Init rclpy with ``argv``'s ROS arguments, make the node and spin it until SIGINT or
    SIGTERM; returns the process exit code (2, with the reason printed after ``prog``, when the
    node refuses its parameters: see :func:`refusal`). ``before_destroy`` stops the
    node's own threads."""
    rclpy.init(args=[node_name, *argv])
    node: N | None = None
    try:
        try:
            node = make_node()
        except (ValueError, ParameterException) as err:
            print(f"{prog}: {refusal(err)}", flush=True)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin_until_shutdown(executor)
    finally:
        if node is not None:
            if before_destroy is not None:
                before_destroy(node)
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def limit_thread_pools(threads: int = 1) -> None:
    """Run OpenCV's and the BLAS's internal parallel loops on ``threads`` threads (process-wide).

    The node already runs two worker threads on machines with few cores; native pools on top of
    them only oversubscribe the cores (OpenBLAS workers also busy-wait after each call). Results
    do not change: only how the work is scheduled.
    """
    cv2.setNumThreads(int(threads))
    threadpool_limits(limits=int(threads), user_api="blas")
