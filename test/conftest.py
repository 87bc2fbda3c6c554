"""Shared test fixtures, session environment and markers.

Session environment (set before any test runs, so node subprocesses and the test process's own
rclpy share it):

- ``ROS_DOMAIN_ID``: one random domain (1..200) per test session, so parallel runs on one
  machine do not see each other.
- ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (unless set): DDS discovery stays on this machine.

Fixtures:

- ``shared_data``: the folder ``../shared/data`` beside the repository (real images with GT F).
  Skips when it is missing, unless ``SEPFM_REQUIRE_SHARED=1`` (CI), where it fails instead.
- ``shared_data_lines``: ``../shared/data_lines`` (line-rich Strecha pairs), the same way; tests
  using it are marked ``shared_data`` too.
- ``compiled_kernels`` (autouse): the estimator's numba kernels compiled (or loaded from the
  on-disk cache) once, before any test, so node subprocesses started by tests load a warm cache
  instead of each compiling for tens of seconds.
- ``ros_domain_id``: the session's ROS_DOMAIN_ID; live tests (real DDS) request it.

The test tree mirrors the package: ``test/geometry``, ``test/pipeline``, ``test/stream``,
``test/ros``, ``test/evaluation``, ``test/fleet``, ``test/benchmarks``, and the whole-package
tests here. ``python -m pytest test/geometry`` runs one layer (the geometry, pipeline, stream and
fleet folders need no rclpy). Helpers shared by several folders (``ros_helpers``, ``robot_bags``,
``ground_truth``, ...) live here; this conftest's folder is on ``sys.path``.

Markers (registered in pyproject.toml): ``ros`` (real DDS) and ``shared_data`` are applied here
to every test that uses the fixture of that name; ``slow`` and ``timing`` are set in the test
modules, or for whole modules by ``MODULE_MARKS`` in each folder's conftest
(:func:`markers.mark_modules`). ``python -m pytest`` runs everything (what CI runs);
``python -m pytest -m "not slow"`` is the fast run while developing.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest
from markers import mark_modules

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"

MODULE_MARKS: dict[str, tuple[str, ...]] = {"test_colcon_run": ("slow",)}


def pytest_configure(config: pytest.Config) -> None:
    """Session environment: a random ROS_DOMAIN_ID and localhost-only DDS discovery."""
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 200))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        names = getattr(item, "fixturenames", ())
        if "ros_domain_id" in names:
            item.add_marker(pytest.mark.ros)
        if "shared_data" in names or "shared_data_lines" in names:
            item.add_marker(pytest.mark.shared_data)
    mark_modules(items, Path(__file__).parent, MODULE_MARKS, recursive=False)


def _shared_folder(folder: Path) -> Path:
    """``folder`` when it holds pairs.json; else skip (or fail with SEPFM_REQUIRE_SHARED=1)."""
    if not (folder / "pairs.json").is_file():
        message = f"shared data not found at {folder}"
        if os.environ.get("SEPFM_REQUIRE_SHARED") == "1":
            pytest.fail(message + " (SEPFM_REQUIRE_SHARED=1)")
        pytest.skip(message)
    return folder


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ../shared/data; skip (or fail with SEPFM_REQUIRE_SHARED=1) when missing."""
    return _shared_folder(SHARED_DATA)


@pytest.fixture(scope="session")
def shared_data_lines() -> Path:
    """Path of ../shared/data_lines (line-rich Strecha pairs); skips or fails as shared_data."""
    return _shared_folder(SHARED_DATA.parent / "data_lines")


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> float:
    """Compile or load the estimator's kernels once per session; returns the seconds spent."""
    from sepfm_ros.pipeline.compiled import warm_up

    return warm_up()


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """The session's ROS_DOMAIN_ID (set in ``pytest_configure``, before any rclpy.init)."""
    return int(os.environ["ROS_DOMAIN_ID"])


@pytest.fixture(scope="module")
def ros(ros_domain_id):
    """One test module's rclpy context, node and background executor (``ros_helpers.Ros``).
    Requested only by modules that skip without rclpy, so rclpy is imported here, not above."""
    from ros_helpers import Ros

    r = Ros()
    yield r
    r.close()
