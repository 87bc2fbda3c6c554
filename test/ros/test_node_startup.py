"""SIGINT / SIGTERM stop the node cleanly while it compiles its kernels (a fresh install)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from shell_jobs import as_background_job

from sepfm_ros.ros.node.spin import spin_until_shutdown


@pytest.mark.parametrize(
    "sig, background",
    [(signal.SIGINT, False), (signal.SIGTERM, False), (signal.SIGINT, True)],
    ids=["SIGINT", "SIGTERM", "SIGINT-background"],
)
def test_signal_during_kernel_compilation_exits_cleanly(sig, background, tmp_path, ros_domain_id):
    cache = tmp_path / "numba"  # an empty kernel cache: the node has to compile (tens of seconds)
    cache.mkdir()
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    proc = subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "node"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=as_background_job if background else None,
    )
    try:
        deadline = time.monotonic() + 120.0
        # numba makes the cache folders at import; the first file is the first compiled kernel
        while not any(p.is_file() for p in cache.rglob("*")):
            assert proc.poll() is None, proc.communicate()[0]
            assert time.monotonic() < deadline, "the node never started compiling"
            time.sleep(0.1)
        t0 = time.monotonic()
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=15)
        elapsed = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    assert "interrupted while preparing the estimator" in out, out
    assert "Traceback" not in out, out
    assert "kernels ready" not in out, out  # it stopped without finishing the compilation
    print(f"[startup] {sig.name} during kernel compilation: exit 0 after {elapsed:.2f} s")


# Modules the live node never uses: bag reading and writing (rosbags' rosbag2/rosbag1 readers,
# type system and serialisers) and the progress bar and plots of the offline commands. The
# image encoding table of rosbags-image (rosbags.image) is used and allowed.
NODE_FORBIDDEN = ("rosbags.rosbag2", "rosbags.rosbag1", "rosbags.typesys", "rosbags.serde")
NODE_FORBIDDEN += ("rosbags.highlevel", "tqdm", "matplotlib")


def test_node_command_imports_no_bag_or_progress_bar_modules():
    pytest.importorskip("rclpy")
    code = (
        "import sys, sepfm_ros.cli, sepfm_ros.ros.commands.node;"
        f"bad = sorted(m for m in sys.modules if m.startswith({NODE_FORBIDDEN!r}));"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"the node imports {r.stdout.strip()}\n{r.stderr[-2000:]}"


# The estimator's modules (numba's compiler, scipy, the pipeline and the answers built from it):
# loaded by the kernel warm-up thread and at configure, after the lifecycle node is in the graph.
# Importing them first took about a second and a half, most of the 2 s the node has to appear.
STARTUP_FORBIDDEN = ("numba", "scipy", "ruamel", "sepfm_ros.geometry.estimator")
STARTUP_FORBIDDEN += ("sepfm_ros.pipeline.pipeline", "sepfm_ros.ros.session.answer")


@pytest.mark.parametrize("command", ["node", "rectify"])
def test_node_start_up_path_leaves_the_estimator_modules_to_the_warm_up(command):
    pytest.importorskip("rclpy")
    code = (
        f"import sys, sepfm_ros.cli, sepfm_ros.ros.commands.{command};"
        f"bad = sorted(m for m in sys.modules if m.startswith({STARTUP_FORBIDDEN!r}));"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"start-up imports {r.stdout.strip()}\n{r.stderr[-2000:]}"


class _ShutDuringSpin(SingleThreadedExecutor):
    """An executor whose context is shut down (as rclpy's SIGTERM handler does) right after
    spin checked it and before the wait set is built: the race a signal can hit."""

    def spin_once(self, timeout_sec=None):
        self.context.shutdown()
        super().spin_once(timeout_sec)


class _FailsWhileUp(SingleThreadedExecutor):
    def spin_once(self, timeout_sec=None):
        raise RuntimeError("a callback failed")


def test_spin_ends_quietly_when_a_signal_shuts_the_context_mid_spin():
    context = rclpy.Context()
    rclpy.init(context=context)
    executor = _ShutDuringSpin(context=context)
    with pytest.raises(Exception) as raised:  # what the race does to a bare spin
        executor.spin()
    assert not context.ok() and "context is not valid" in str(raised.value)
    context = rclpy.Context()
    rclpy.init(context=context)
    spin_until_shutdown(_ShutDuringSpin(context=context))  # returns: the shutdown
    assert not context.ok()


def test_spin_reraises_errors_while_the_context_is_up():
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(RuntimeError, match="a callback failed"):
            spin_until_shutdown(_FailsWhileUp(context=context))
    finally:
        context.try_shutdown()


@pytest.mark.parametrize("command", ["node", "rectify"])
def test_a_node_refuses_a_bad_parameter_or_a_non_ros_argument_with_exit_2(command, ros_domain_id):
    """Out of range: the parameter's error, exit 2, no traceback; an argument that is not a ROS
    argument: the usage, exit 2 (before rclpy starts)."""
    run = [sys.executable, "-m", "sepfm_ros", command]
    range_, type_ = {
        "node": ("threshold_px:=-1.0", "threshold_px:=wide"),
        "rectify": ("min_inliers:=3", "min_inliers:=many"),
    }[command]
    for bad in (range_, type_, "image_transport:=carrier_pigeon"):
        r = subprocess.run(
            [*run, "--ros-args", "-p", bad], capture_output=True, text=True, timeout=600
        )
        out = r.stdout + r.stderr
        assert r.returncode == 2, out
        assert f"sepfm_ros {command}: invalid parameters" in out, out
        assert bad.split(":=")[0] in out and "Traceback" not in out, out
    # remaps to what is not a topic name (rcl refuses them as it parses the arguments)
    for rule in ("bad topic", "9bad"):
        remap = [*run, "--ros-args", "-r", f"left/image_raw:={rule}"]
        r = subprocess.run(remap, capture_output=True, text=True, timeout=600)
        out = r.stdout + r.stderr
        assert r.returncode == 2 and f"sepfm_ros {command}: invalid ROS arguments" in out, out
        assert "Traceback" not in out, out
    r = subprocess.run([*run, "--frobnicate"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and f"usage: sepfm_ros {command}" in r.stderr, r.stderr
    assert "--frobnicate" in r.stderr


@pytest.mark.parametrize("command", ["record", "replay"])
def test_record_and_replay_refuse_ros_arguments_rcl_cannot_parse(command, tmp_path):
    out = tmp_path / "out"
    own = {"record": ["/chatter", "-o", str(out)], "replay": [str(tmp_path / "bag")]}[command]
    r = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", command, *own, "--ros-args", "-r", "a:=b c"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 2 and f"sepfm_ros {command}: invalid ROS arguments" in r.stderr
    assert "Traceback" not in r.stderr and not out.exists(), r.stderr
