"""The ``ros2 run sepfm_ros node`` contract, without ros2cli (not on PyPI).

The repository is put under ``src/`` of a temporary workspace (a symlink) and built as a ROS user
does, with colcon-core + colcon-ros from PyPI. A plain ``colcon build`` builds sepfm_ros only:
colcon stops at the root package.xml and never sees the nested interface package, so the built
node's first start must fail with one line naming the fix, without a traceback (started where
only a colcon-built sepfm_msgs could be imported, test_missing_interfaces.py). The command that
line names is then run verbatim in the workspace and builds both packages, sepfm_msgs
(ament_cmake, against this environment's ROS wheels) and sepfm_ros. The package prefix is looked
up with ament_index_python exactly as ``ros2 run`` does, and ``<prefix>/lib/sepfm_ros/node`` is
run from there (with the installed config file) until it publishes its /diagnostics report.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import sysconfig
import threading
import time
from pathlib import Path

import pytest
from optional_tools import missing_tool
from test_missing_interfaces import without_pip_sepfm_msgs

from sepfm_ros.ros.node.lifecycle import WARMING_UP

rclpy = pytest.importorskip("rclpy")

REPO = Path(__file__).resolve().parent.parent


def _colcon() -> str:
    colcon = Path(sys.executable).parent / "colcon"
    found = str(colcon) if colcon.exists() else shutil.which("colcon")
    if not found:
        missing_tool("colcon", "pip install colcon-core colcon-ros, or pip install -e '.[test]'")
    return str(found)


def _user_env() -> dict[str, str]:
    """This virtual environment activated, as the user who runs colcon has it."""
    env = dict(os.environ)
    env["VIRTUAL_ENV"] = sys.prefix  # CMake's FindPython3 takes the active environment's
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    return env


@pytest.fixture(scope="module")
def plain_build(tmp_path_factory) -> dict[str, object]:
    """A plain ``colcon build`` of a workspace holding the repository as ``src/sepfm_ros``, and
    the output of the built node's first start where sepfm_msgs is not importable."""
    ws = tmp_path_factory.mktemp("colcon_ws")
    (ws / "src").mkdir()
    (ws / "src" / "sepfm_ros").symlink_to(REPO, target_is_directory=True)
    env = _user_env()
    done = subprocess.run(
        [_colcon(), "build"], cwd=ws, env=env, capture_output=True, text=True, timeout=900
    )
    assert done.returncode == 0, done.stdout + done.stderr
    # sourced install/setup.sh (colcon-core's; setup.bash is colcon-bash's), then `ros2 run`
    start = '. "$1/install/setup.sh" && exec "$1/install/sepfm_ros/lib/sepfm_ros/node"'
    node = subprocess.run(
        ["sh", "-c", start, "sh", str(ws)],
        cwd=ws,
        env=without_pip_sepfm_msgs(ws.parent / f"{ws.name}_hide", env),
        capture_output=True,
        text=True,
        timeout=300,
    )
    return {"ws": ws, "build": done.stdout, "node": node}


def test_plain_colcon_build_gives_a_node_that_names_the_fix_in_one_line(plain_build):
    ws, build, node = plain_build["ws"], plain_build["build"], plain_build["node"]
    assert "Finished <<< sepfm_ros" in build, build
    assert "sepfm_msgs" not in build, build  # colcon did not look inside sepfm_ros's folder
    output = node.stdout + node.stderr
    assert node.returncode == 1, output
    assert "Traceback" not in output, output
    assert output.strip().count("\n") == 0, output  # one line
    assert output.startswith("sepfm_ros: the interface package sepfm_msgs is not built"), output
    assert f"`colcon build --base-paths src src/sepfm_ros/sepfm_msgs` in {ws}" in output, output


@pytest.fixture(scope="module")
def colcon_install(plain_build) -> Path:
    """The workspace after the command the node's one line names, run there verbatim."""
    ws, line = plain_build["ws"], plain_build["node"].stderr
    fix = re.search(r"`(colcon build [^`]*)`", line)
    assert fix, line
    cmd = [_colcon(), *shlex.split(fix.group(1))[1:]]
    done = subprocess.run(
        cmd, cwd=ws, env=_user_env(), capture_output=True, text=True, timeout=1800
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "Finished <<< sepfm_msgs" in done.stdout, done.stdout
    assert "Finished <<< sepfm_ros" in done.stdout, done.stdout
    return ws / "install"


def installed_env(install: Path) -> dict[str, str]:
    """What sourcing install/setup.sh sets for this package: AMENT_PREFIX_PATH and PYTHONPATH."""
    prefix = install / "sepfm_ros"
    purelib = Path(sysconfig.get_path("purelib", vars={"base": str(prefix)}))
    rel = purelib.relative_to(prefix)
    site = prefix / rel
    assert (site / "sepfm_ros" / "cli.py").is_file(), f"package not installed in {site}"
    env = dict(os.environ)
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(
        [str(prefix), *filter(None, [os.environ.get("AMENT_PREFIX_PATH")])]
    )
    env["PYTHONPATH"] = os.pathsep.join([str(site), *filter(None, [env.get("PYTHONPATH")])])
    env["PYTHONUNBUFFERED"] = "1"
    return env


def test_colcon_build_installs_executables_and_share_files(colcon_install):
    prefix = colcon_install / "sepfm_ros"
    for name in ("node", "make_bag", "replay", "record", "process", "eval", "warm_up", "rectify"):
        assert os.access(prefix / "lib" / "sepfm_ros" / name, os.X_OK), name
    share = prefix / "share" / "sepfm_ros"
    assert (share / "package.xml").is_file()
    assert (share / "rosdep.yaml").is_file()
    assert (share / "config" / "sepfm.yaml").is_file()
    assert (share / "launch" / "sepfm_launch.py").is_file()
    assert (colcon_install.parent / "install").is_dir()
    index = prefix / "share" / "ament_index" / "resource_index" / "packages" / "sepfm_ros"
    assert index.is_file()


def test_colcon_built_interface_package_serialises_its_messages(colcon_install, tmp_path):
    # what sourcing install/setup.sh gives sepfm_msgs: its site-packages and its libraries first
    prefix = colcon_install / "sepfm_msgs"
    site = prefix / Path(sysconfig.get_path("purelib", vars={"base": str(prefix)})).relative_to(
        prefix
    )
    assert (prefix / "share" / "sepfm_msgs" / "msg" / "TwoViewEstimate.msg").is_file()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), *filter(None, [env.get("PYTHONPATH")])])
    env["LD_LIBRARY_PATH"] = os.pathsep.join(
        [str(prefix / "lib"), *filter(None, [env.get("LD_LIBRARY_PATH")])]
    )
    code = (
        "import sepfm_msgs; from sepfm_msgs.msg import TwoViewEstimate as T;"
        "from rclpy.serialization import serialize_message as s, deserialize_message as d;"
        "m = d(s(T(status_text='built by colcon', inliers=7)), T);"
        "print(sepfm_msgs.__file__); print(m.status_text, m.inliers, T.STATUS_BAD_INPUT);"
        "from sepfm_ros.ros.bags.types import sepfm_msgs_share; print(sepfm_msgs_share())"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    module_file, values, share = r.stdout.splitlines()
    assert Path(module_file).is_relative_to(prefix), module_file  # colcon's, not pip's copy
    assert values == "built by colcon 7 5"
    assert Path(share) == prefix / "share" / "sepfm_msgs"  # where bags get the definitions


def test_ros2_run_warm_up_caches_kernels_inside_the_install(colcon_install, tmp_path):
    # `ros2 run sepfm_ros warm_up` after `colcon build`: the kernel cache must be writable
    # there, beside the installed modules, so later node starts load it
    env = installed_env(colcon_install)
    env.pop("NUMBA_CACHE_DIR", None)
    executable = colcon_install / "sepfm_ros" / "lib" / "sepfm_ros" / "warm_up"
    runs = []
    for _ in range(2):
        r = subprocess.run(
            [str(executable)], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=900
        )
        assert r.returncode == 0, r.stdout + r.stderr
        runs.append(r.stdout)
    caches = [
        Path(line.split("cache: ", 1)[1]) for line in runs[0].splitlines() if "cache: " in line
    ]
    assert caches and all(c.is_relative_to(colcon_install) for c in caches), runs[0]
    assert all(any(c.glob("*.nbi")) for c in caches), runs[0]
    assert "nothing to compile" in runs[1], runs[1]


def test_ros2_run_node_from_the_ament_prefix_publishes(colcon_install, ros_domain_id, tmp_path):
    env = installed_env(colcon_install)
    # look the package up the way `ros2 run` does (ament_index_python), in the installed env
    lookup = subprocess.run(
        [
            sys.executable,
            "-c",
            "from ament_index_python.packages import get_package_prefix, "
            "get_package_share_directory as share; import sepfm_ros; "
            "print(get_package_prefix('sepfm_ros')); print(share('sepfm_ros')); "
            "print(sepfm_ros.__file__)",
        ],
        env=env,
        cwd=tmp_path,  # not the source tree, which would shadow the installed copy
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert lookup.returncode == 0, lookup.stderr
    prefix, share, module_file = lookup.stdout.split()
    assert Path(prefix) == colcon_install / "sepfm_ros"
    assert Path(module_file).is_relative_to(colcon_install), module_file  # the installed copy
    executable = Path(prefix) / "lib" / "sepfm_ros" / "node"

    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    name = "sepfm_colcon"
    seen = threading.Event()
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("sepfm_colcon_test", context=context)

    def on_diag(msg):
        # the node's own status once it has its kernels (its "warming up" status comes first,
        # from start-up on, while it compiles or loads them)
        if any(s.name == f"/{name}: node" and s.message != WARMING_UP for s in msg.status):
            seen.set()

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    log = tmp_path / "node.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [str(executable), "--ros-args", "-r", f"__node:={name}"]
            + ["--params-file", str(Path(share) / "config" / "sepfm.yaml")],
            env=env,
            cwd=tmp_path,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
        try:
            # a fresh prefix compiles the estimator's numba kernels on the node's first start
            # (cached beside the installed modules afterwards): allow for it
            deadline = time.monotonic() + 240.0
            while not seen.is_set() and time.monotonic() < deadline and proc.poll() is None:
                executor.spin_once(timeout_sec=0.1)
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                code = proc.wait(15)
            except subprocess.TimeoutExpired:  # never leave a node behind
                proc.kill()
                proc.wait()
                raise
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=context)
    output = log.read_text()
    assert seen.is_set(), f"no /diagnostics from {executable}:\n{output}"
    assert "estimator kernels ready" in output, output
    assert code == 0, output
