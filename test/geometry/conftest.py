"""Tests of sepfm_ros.geometry (the estimator core; no ROS, no rclpy needed)."""

from __future__ import annotations

from pathlib import Path

import pytest
from markers import mark_modules

# whole modules that are slow (more than about half a minute on a 2-core machine) or whose
# assertions bound latency or throughput (``timing``); other modules mark themselves
MODULE_MARKS: dict[str, tuple[str, ...]] = {}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    mark_modules(items, Path(__file__).parent, MODULE_MARKS)
