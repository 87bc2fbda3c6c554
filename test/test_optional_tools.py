"""A missing developer tool skips its tests on a ROS machine and fails them under CI."""

from __future__ import annotations

import pytest
from optional_tools import missing_tool, tools_required


@pytest.mark.parametrize(
    ("env", "required"),
    [
        ({}, False),
        ({"CI": "true"}, True),
        ({"CI": "TRUE"}, True),
        ({"CI": "false"}, False),
        ({"SEPFM_REQUIRE_SHARED": "1"}, True),
        ({"SEPFM_REQUIRE_SHARED": "0"}, False),
    ],
)
def test_missing_tool_skips_unless_ci_requires_it(monkeypatch, env, required):
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.delenv("SEPFM_REQUIRE_SHARED", raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    assert tools_required() is required
    expected = pytest.fail.Exception if required else pytest.skip.Exception
    with pytest.raises(expected, match="ruff is not installed \\(pip install ruff\\)"):
        missing_tool("ruff", "pip install ruff")
