"""Command-line options that several commands share, declared once."""

from __future__ import annotations

import argparse


def add_topic_arguments(p: argparse.ArgumentParser) -> None:
    """``--left``/``--right``/``--image``: the input topics (shared by process and eval --bags)."""
    p.add_argument("--left", metavar="TOPIC", help="stereo: left image topic (with --right)")
    p.add_argument("--right", metavar="TOPIC", help="stereo: right image topic (with --left)")
    p.add_argument("--image", metavar="TOPIC", help="motion: the image topic")
