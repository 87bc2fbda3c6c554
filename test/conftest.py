"""Shared test fixtures.

- ``shared_data``: the folder ``../shared/data`` beside the repository (real images with GT F).
  Skips when it is missing, unless ``SEPFM_REQUIRE_SHARED=1`` (CI), where it fails instead.
- ``compiled_kernels`` (autouse): the estimator's numba kernels compiled (or loaded from the
  on-disk cache) once, before any test, so node subprocesses started by tests load a warm cache
  instead of each compiling for tens of seconds.
- ``ros_domain_id``: one random ROS_DOMAIN_ID (1..200) per test session, set in ``os.environ``
  so node subprocesses and the test process's own rclpy share it and no other run.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ../shared/data; skip (or fail with SEPFM_REQUIRE_SHARED=1) when missing."""
    if not (SHARED_DATA / "pairs.json").is_file():
        message = f"shared data not found at {SHARED_DATA}"
        if os.environ.get("SEPFM_REQUIRE_SHARED") == "1":
            pytest.fail(message + " (SEPFM_REQUIRE_SHARED=1)")
        pytest.skip(message)
    return SHARED_DATA


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> float:
    """Compile or load the estimator's kernels once per session; returns the seconds spent."""
    from sepfm_ros.pipeline.compiled import warm_up

    return warm_up()


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """A random ROS_DOMAIN_ID for this test session, exported before anyone calls rclpy.init."""
    domain = random.SystemRandom().randint(1, 200)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    return domain
