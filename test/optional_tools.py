"""Tests that need a tool the package itself does not (ruff, colcon): skip when it is missing.
Tests of a detector this environment's OpenCV may lack (AKAZE): skip with the package's reason.

On a ROS machine (``colcon test``) a developer tool may be absent: such a test skips with the
reason and the install command. Under CI (``CI=true``) or with ``SEPFM_REQUIRE_SHARED=1``, where
``.ci/run`` installs every tool, a missing one fails instead, as missing shared data does.
"""

from __future__ import annotations

import os

import pytest

from sepfm_ros.pipeline.features import unavailable_reason


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


def detector_param(features: str) -> object:
    """``features`` as a pytest parameter, skipped when this environment's ``cv2`` cannot create
    that detector (AKAZE with OpenCV 5's main wheel), the reason being the package's own error
    with its fix. Not an error under CI: the package installs the main wheel."""
    reason = unavailable_reason(features)
    return pytest.param(features, marks=pytest.mark.skipif(reason is not None, reason=str(reason)))
