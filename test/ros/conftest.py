"""Tests of sepfm_ros.ros: messages, the node over real DDS, bags, process, replay, record."""

from __future__ import annotations

from pathlib import Path

import pytest
from markers import mark_modules

# whole modules that are slow (more than about half a minute on a 2-core machine) or whose
# assertions bound latency or throughput (``timing``); other modules mark themselves
MODULE_MARKS: dict[str, tuple[str, ...]] = {
    "test_node_live": ("slow", "timing"),
    "test_robustness_live": ("slow", "timing"),
    "test_robustness_bags": ("slow",),
    "test_bags_replay": ("slow",),
}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    mark_modules(items, Path(__file__).parent, MODULE_MARKS)
