"""The stream logic (:mod:`sepfm_ros.stream`) imports without ROS: every module of the package is
imported in a fresh interpreter where rclpy and the ROS message packages cannot be imported."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
# Top-level names whose import (or any submodule's) is refused in the child interpreter.
BLOCKED = ("rclpy", "sensor_msgs", "std_msgs", "diagnostic_msgs", "builtin_interfaces")

# Run by the child: a finder first on sys.meta_path refuses the ROS packages, checks that it does
# (so a passing run cannot come from a blocker that never blocked), then imports every module of
# the package named in argv[1] and prints their names.
CHILD = textwrap.dedent(
    """
    import importlib
    import pkgutil
    import sys

    BLOCKED = set(sys.argv[2].split(","))

    class BlockRos:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"blocked ROS import: {name}")
            return None

    sys.meta_path.insert(0, BlockRos())
    for name in BLOCKED:
        try:
            importlib.import_module(name)
        except ImportError:
            pass
        else:
            raise SystemExit(f"the blocker let {name} through")
    package = importlib.import_module(sys.argv[1])
    names = [package.__name__]
    for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
        importlib.import_module(info.name)
        names.append(info.name)
    print(" ".join(names))
    """
)


def import_without_ros(package: str, extra_path: Path | None = None) -> subprocess.CompletedProcess:
    """Import every module of ``package`` in a child interpreter with the ROS packages blocked."""
    paths = [str(REPO)] + ([str(extra_path)] if extra_path is not None else [])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(paths))
    return subprocess.run(
        [sys.executable, "-c", CHILD, package, ",".join(BLOCKED)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_every_stream_module_imports_without_ros():
    r = import_without_ros("sepfm_ros.stream")
    assert r.returncode == 0, r.stdout + r.stderr
    imported = set(r.stdout.split())
    on_disk = {
        f"sepfm_ros.stream.{f.stem}"
        for f in (REPO / "sepfm_ros" / "stream").glob("*.py")
        if f.stem != "__init__"
    }
    assert on_disk >= {f"sepfm_ros.stream.{m}" for m in ("pairing", "sync", "scheduling", "health")}
    assert imported == on_disk | {"sepfm_ros.stream"}


def test_a_planted_ros_import_fails_the_check(tmp_path):
    # a module that reaches ROS only through another module of the project, as a careless
    # import of a ROS adapter would
    pkg = tmp_path / "planted_stream"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "clean.py").write_text("from sepfm_ros.stream.sync import ApproximateTimeSync\n")
    (pkg / "careless.py").write_text("from sepfm_ros.ros.msgs.headers import stamp_ns\n")
    r = import_without_ros("planted_stream", extra_path=tmp_path)
    assert r.returncode != 0
    assert "blocked ROS import" in r.stderr, r.stderr
