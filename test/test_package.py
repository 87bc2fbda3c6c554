"""Package-level checks: lint and format (ruff), the console command, the ROS-free core."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent


def _ruff() -> list[str]:
    exe = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    if not Path(exe).exists():
        pytest.fail("ruff is not installed (it is part of the 'test' extra)")
    return [exe]


def test_ruff_lint_passes():
    r = subprocess.run([*_ruff(), "check", "."], cwd=REPO_ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_ruff_format_is_clean():
    r = subprocess.run(
        [*_ruff(), "format", "--check", "."], cwd=REPO_ROOT, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_console_command_lists_every_subcommand():
    r = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "--help"], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 0
    for name in ("node", "make_bag", "replay", "record", "process", "eval", "demo"):
        assert f"  {name}" in r.stdout
    r = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "no_such_command"], capture_output=True, text=True
    )
    assert r.returncode == 2 and "unknown command" in r.stderr


@pytest.mark.parametrize("name", ["node", "make_bag", "replay", "record", "process", "eval"])
def test_every_subcommand_has_help(name):
    r = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", name, "--help"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "usage" in r.stdout.lower()


def test_geometry_core_imports_no_ros():
    code = (
        "import sys, sepfm_ros.geometry, sepfm_ros.pipeline.features;"
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('rclpy', 'sensor_msgs', 'std_msgs', 'diagnostic_msgs', 'rosbags')];"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
