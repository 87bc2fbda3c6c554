"""The test tree mirrors the package, and the ROS-free layers' tests run without rclpy."""

from __future__ import annotations

import os
import subprocess
import sys

from ground_truth import REPO_ROOT

TEST = REPO_ROOT / "test"
# folders whose tests must collect and run where rclpy and the ROS messages are not importable
ROS_FREE = ("geometry", "pipeline", "stream")
BLOCKED = (
    "rclpy",
    "sensor_msgs",
    "std_msgs",
    "diagnostic_msgs",
    "builtin_interfaces",
    "sepfm_msgs",
)


def test_every_test_folder_mirrors_a_package_folder():
    folders = sorted(p.name for p in TEST.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert folders, "no test folders"
    for name in folders:
        assert (REPO_ROOT / "sepfm_ros" / name).is_dir() or (REPO_ROOT / name).is_dir(), name
        assert (TEST / name / "conftest.py").is_file(), f"test/{name} has no conftest.py"
        assert any((TEST / name).glob("test_*.py")), f"test/{name} holds no tests"


def test_ros_free_layers_collect_without_rclpy():
    """``pytest test/geometry`` (and pipeline, stream) where rclpy cannot be imported."""
    code = (
        "import sys, pytest\n"
        f"for name in {BLOCKED!r}:\n"
        "    sys.modules[name] = None  # import raises ImportError\n"
        "sys.exit(pytest.main(['--collect-only', '-q', '-p', 'no:cacheprovider', *sys.argv[1:]]))\n"
    )
    folders = [str(TEST / name) for name in ROS_FREE]
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")])
    )
    run = subprocess.run(
        [sys.executable, "-c", code, *folders],
        cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert " collected" in run.stdout or "tests collected" in run.stdout, run.stdout[-2000:]
    for name in ROS_FREE:
        assert f"test/{name}/" in run.stdout, f"nothing collected in test/{name}"
