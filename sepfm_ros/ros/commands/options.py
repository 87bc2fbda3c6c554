"""Command-line options that several commands share, declared once.

- :func:`add_topic_arguments`: ``--left``/``--right``/``--image``, the input image topics;
- :func:`add_param_arguments`: ``-p NAME:=VALUE`` and ``--params-file FILE``, the node's
  parameters (:mod:`sepfm_ros.ros.session.parameters`), read by :func:`given_params_of`.

Importing this module needs no ROS packages (``eval`` declares its ``--bags`` options with it).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sepfm_ros.ros.session.parameters import GivenParams


def add_topic_arguments(p: argparse.ArgumentParser, prefix: str = "", motion: bool = True) -> None:
    """``--left``/``--right`` and, where ``motion``, ``--image``: the input topics (default:
    picked from the bag). ``prefix``: words before each help text (e.g. ``--bags:``)."""
    flags = [
        ("--left", "stereo: left image topic (with --right)"),
        ("--right", "stereo: right image topic (with --left)"),
    ]
    if motion:
        flags.append(("--image", "motion: the image topic"))
    for flag, text in flags:
        p.add_argument(flag, metavar="TOPIC", help=f"{prefix}{text}; default: picked from the bag")


def add_param_arguments(
    p: argparse.ArgumentParser, example: str = "seed:=0, features:=sift"
) -> None:
    """``-p/--param NAME:=VALUE`` (repeatable) and ``--params-file FILE``: the node's parameters,
    as ``--ros-args -p`` and ``--params-file`` give them to the live node."""
    p.add_argument(
        "-p",
        "--param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help=f"a node parameter (e.g. {example}; `sepfm_ros node --help` lists them); "
        "repeatable, and overrides --params-file",
    )
    p.add_argument(
        "--params-file",
        type=Path,
        metavar="FILE",
        help="the node's parameters from a ROS 2 params file (the ros__parameters of its /** or "
        "sepfm section, as config/sepfm.yaml)",
    )


def given_params_of(args: argparse.Namespace) -> GivenParams:
    """The parameter values of :func:`add_param_arguments`' options (ParameterError when one
    cannot be used)."""
    from sepfm_ros.ros.session.parameters import given_params

    return given_params(args.param, args.params_file)
