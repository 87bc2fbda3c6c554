"""Tests that need a tool the package itself does not (ruff, colcon): skip when it is missing.

On a ROS machine (``colcon test``) a developer tool may be absent: such a test skips with the
reason and the install command. Under CI (``CI=true``) or with ``SEPFM_REQUIRE_SHARED=1``, where
``.ci/run`` installs every tool, a missing one fails instead, as missing shared data does.
"""

from __future__ import annotations

import os

import pytest


def tools_required() -> bool:
    """True under CI or SEPFM_REQUIRE_SHARED=1: a missing tool is an error, not a skip."""
    return (
        os.environ.get("CI", "").lower() == "true" or os.environ.get("SEPFM_REQUIRE_SHARED") == "1"
    )


def missing_tool(name: str, install: str) -> None:
    """Skip the calling test (or fail it, see :func:`tools_required`): ``name`` is missing."""
    message = f"{name} is not installed ({install})"
    if tools_required():
        pytest.fail(f"{message}; required under CI / SEPFM_REQUIRE_SHARED=1")
    pytest.skip(message)
