"""Both nodes as lifecycle nodes driven from an rclpy client over real DDS (lifecycle_msgs
ChangeState / GetState), and the sepfm node's demand: no image subscription without a subscriber
of its answers, a subscription once one appears, fresh answers, ``always_on``; and the node in
the graph, answering get_state, while its kernels still compile."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from lifecycle_msgs.msg import State, Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from ros_helpers import (  # noqa: E402
    RELIABLE,
    STARTUP_TIMEOUT,
    Client,
    NodeProcess,
    call_service,
    image_msg,
)
from sensor_msgs.msg import Image  # noqa: E402

from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402

RNG = np.random.default_rng(7)
TEXTURE = (RNG.random((240, 320)) * 255).astype(np.uint8)


class Lifecycle:
    """A lifecycle manager of one node (its ~/change_state and ~/get_state services)."""

    def __init__(self, ros, name: str) -> None:
        self.ros = ros
        self.change = ros.node.create_client(ChangeState, f"/{name}/change_state")
        self.get = ros.node.create_client(GetState, f"/{name}/get_state")

    def state(self, timeout: float = 60.0) -> int:
        return call_service(self.get, GetState.Request(), timeout).current_state.id

    def wait_state(self, state_id: int, timeout: float = STARTUP_TIMEOUT) -> None:
        deadline = time.monotonic() + timeout
        while self.state() != state_id:
            assert time.monotonic() < deadline, f"state {state_id} never reached"
            time.sleep(0.2)

    def refused(self, transition_id: int) -> bool:
        """Whether the node refuses ``transition_id`` (not one of its state's) and stays."""
        before = self.state()
        request = ChangeState.Request(transition=Transition(id=transition_id))
        return not call_service(self.change, request).success and self.state() == before

    def transition(self, transition_id: int, expect: int) -> None:
        request = ChangeState.Request(transition=Transition(id=transition_id))

        def took_place() -> ChangeState.Response | None:
            # the transition was carried out and only its answer lost: sending it again
            # would be refused from the new state
            return ChangeState.Response(success=True) if self.state() == expect else None

        response = call_service(self.change, request, answered=took_place)
        assert response.success, f"transition {transition_id}"
        assert self.state() == expect


class Diagnostics:
    """The /diagnostics statuses of one node, with their receipt time."""

    def __init__(self, ros, name: str) -> None:
        self.lock = threading.Lock()
        self.seen: list[tuple[float, str]] = []  # (time.monotonic(), message)
        self.name = name
        self.sub = ros.node.create_subscription(DiagnosticArray, "/diagnostics", self._on, RELIABLE)

    def _on(self, msg) -> None:
        with self.lock:
            for status in msg.status:
                if status.name.startswith(f"{self.name}:") or f"/{self.name}:" in status.name:
                    self.seen.append((time.monotonic(), status.message))

    def since(self, t: float) -> list[str]:
        with self.lock:
            return [m for at, m in self.seen if at >= t]

    def wait(self, text: str, after: float, timeout: float = 60.0) -> float:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                hits = [at for at, m in self.seen if at >= after and text in m]
            if hits:
                return hits[0]
            time.sleep(0.05)
        raise AssertionError(f"no /diagnostics {text!r} from {self.name}: {self.since(after)}")


class Camera:
    """A camera publishing ``topic`` at 10 Hz from a thread; the stamps it sent, by send time."""

    def __init__(self, ros, topic: str) -> None:
        self.pub = ros.node.create_publisher(Image, topic, RELIABLE)
        self.sent: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._stamp = time.time_ns()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._stamp += 100_000_000
            self.pub.publish(image_msg(np.roll(TEXTURE, len(self.sent), axis=1), self._stamp))
            self.sent.append((time.monotonic(), self._stamp))
            time.sleep(0.1)

    def stop(self) -> None:
        self._stop.set()
        self.thread.join()


def _wait(condition, what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def _stopped(proc: NodeProcess) -> None:
    proc.stop()
    assert "Traceback" not in proc.output(), proc.output()


def test_sepfm_node_every_transition_and_silent_when_deactivated(ros, tmp_path):
    name = "lc_sepfm"
    proc = NodeProcess(name, tmp_path, "-p", "mode:=motion", "-p", "autostart:=false")
    manager = Lifecycle(ros, name)
    diagnostics = Diagnostics(ros, name)
    camera = Camera(ros, "/image_raw")
    try:
        assert manager.state() == State.PRIMARY_STATE_UNCONFIGURED  # autostart:=false waits
        assert ros.node.count_publishers(f"/{name}/estimate") == 0
        # a transition the state does not have is refused; the node keeps serving
        assert manager.refused(Transition.TRANSITION_ACTIVATE)
        manager.transition(Transition.TRANSITION_CONFIGURE, State.PRIMARY_STATE_INACTIVE)
        _wait(lambda: ros.node.count_publishers(f"/{name}/estimate") == 1, "no ~/estimate")
        manager.transition(Transition.TRANSITION_ACTIVATE, State.PRIMARY_STATE_ACTIVE)
        client = Client(ros, name, {})
        _wait(lambda: len(client.info) > 0, f"no answer while active:\n{proc.output()}")
        manager.transition(Transition.TRANSITION_DEACTIVATE, State.PRIMARY_STATE_INACTIVE)
        _wait(lambda: ros.node.count_subscribers("/image_raw") == 0, "inputs held when inactive")
        time.sleep(1.0)  # answers of pairs in flight at the transition
        with client.lock:
            answers, matches = len(client.info), len(client.matches)
        quiet_from = time.monotonic()
        sent_before = len(camera.sent)
        time.sleep(4.0)
        assert len(camera.sent) > sent_before + 10  # the camera kept publishing
        with client.lock:
            assert (len(client.info), len(client.matches)) == (answers, matches)
        assert diagnostics.since(quiet_from) == []  # not even /diagnostics
        manager.transition(Transition.TRANSITION_ACTIVATE, State.PRIMARY_STATE_ACTIVE)
        _wait(lambda: len(client.info) > answers, "no answer after activating again")
        manager.transition(Transition.TRANSITION_DEACTIVATE, State.PRIMARY_STATE_INACTIVE)
        manager.transition(Transition.TRANSITION_CLEANUP, State.PRIMARY_STATE_UNCONFIGURED)
        _wait(lambda: ros.node.count_publishers(f"/{name}/estimate") == 0, "outputs kept")
        manager.transition(Transition.TRANSITION_CONFIGURE, State.PRIMARY_STATE_INACTIVE)
        manager.transition(Transition.TRANSITION_INACTIVE_SHUTDOWN, State.PRIMARY_STATE_FINALIZED)
        assert proc.proc.poll() is None  # finalized, still answering get_state
    finally:
        camera.stop()
        _stopped(proc)


def test_rectify_node_every_transition_and_silent_when_deactivated(ros, tmp_path):
    name = "lc_rectify"
    proc = NodeProcess(name, tmp_path, "-p", "autostart:=false", command="rectify")
    manager = Lifecycle(ros, name)
    diagnostics = Diagnostics(ros, name)
    left = ros.node.create_publisher(Image, "/left/image_raw", RELIABLE)
    try:
        assert manager.state() == State.PRIMARY_STATE_UNCONFIGURED
        t0 = time.monotonic()
        manager.transition(Transition.TRANSITION_CONFIGURE, State.PRIMARY_STATE_INACTIVE)
        time.sleep(3.0)
        assert diagnostics.since(t0) == []
        assert ros.node.count_subscribers("/left/image_raw") == 0
        manager.transition(Transition.TRANSITION_ACTIVATE, State.PRIMARY_STATE_ACTIVE)
        _wait(lambda: ros.node.count_subscribers("/left/image_raw") == 1, "no image input")
        diagnostics.wait("waiting for a good estimate", t0)
        manager.transition(Transition.TRANSITION_DEACTIVATE, State.PRIMARY_STATE_INACTIVE)
        _wait(lambda: ros.node.count_subscribers("/left/image_raw") == 0, "inputs held")
        time.sleep(1.0)
        quiet_from = time.monotonic()
        time.sleep(3.0)
        assert diagnostics.since(quiet_from) == []
        manager.transition(Transition.TRANSITION_CLEANUP, State.PRIMARY_STATE_UNCONFIGURED)
        manager.transition(
            Transition.TRANSITION_UNCONFIGURED_SHUTDOWN, State.PRIMARY_STATE_FINALIZED
        )
    finally:
        ros.node.destroy_publisher(left)
        _stopped(proc)


def test_demand_subscribes_for_the_first_subscriber_and_answers_fresh_pairs(ros, tmp_path):
    name = "demand_sepfm"
    manager = Lifecycle(ros, name)
    diagnostics = Diagnostics(ros, name)
    camera = Camera(ros, "/demand/image_raw")
    remap = ("-r", "image_raw:=/demand/image_raw")
    proc = NodeProcess(name, tmp_path, "-p", "mode:=motion", *remap)  # autostart, on demand
    try:
        manager.wait_state(State.PRIMARY_STATE_ACTIVE)
        t_active = time.monotonic()
        diagnostics.wait("idle: no subscribers", t_active)
        time.sleep(2.0)  # the camera publishes all along; the node holds no subscription
        assert ros.node.count_subscribers("/demand/image_raw") == 0
        client = Client(ros, name, {})
        _wait(lambda: ros.node.count_subscribers("/demand/image_raw") == 1, "never subscribed")
        subscribed_at = time.monotonic()
        _wait(lambda: len(client.info) > 0, f"no answer:\n{proc.output()}")
        with client.lock:
            first = min(client.info)
        # the camera's stamps sent before the node held a subscription were never answered
        before = [stamp for at, stamp in camera.sent if at < subscribed_at - 1.0]
        assert before and first > max(before)
        assert stamp_ns(client.info[first].header.stamp) == first
        # the subscriber leaves: the node lets its input go
        for sub in client.subs:
            ros.node.destroy_subscription(sub)
        _wait(lambda: ros.node.count_subscribers("/demand/image_raw") == 0, "input kept")
        diagnostics.wait("idle: no subscribers", time.monotonic())
    finally:
        camera.stop()
        _stopped(proc)


@pytest.mark.parametrize(
    "args, topic",
    [
        ((), "/on/left/image_raw"),
        (("-p", "mode:=motion", "-p", "always_on:=true"), "/on/image_raw"),
    ],
    ids=["calibrated-stereo-default", "always_on"],
)
def test_always_on_subscribes_without_subscribers(ros, tmp_path, args, topic):
    name = "always_sepfm"
    camera = Camera(ros, topic)
    proc = NodeProcess(name, tmp_path, "-r", "__ns:=/on", *args)
    manager = Lifecycle(ros, f"on/{name}")
    try:
        manager.wait_state(State.PRIMARY_STATE_ACTIVE)
        _wait(lambda: ros.node.count_subscribers(topic) == 1, f"not subscribed:\n{proc.output()}")
    finally:
        camera.stop()
        _stopped(proc)


def test_in_the_graph_answering_get_state_while_the_kernels_compile(ros, tmp_path):
    """With an empty kernel cache the node compiles for tens of seconds: it answers get_state
    first, and its /diagnostics say it is warming up after that answer (so it answered while
    the kernels were still compiling)."""
    cache = tmp_path / "numba"
    cache.mkdir()
    name = "warm_sepfm"
    diagnostics = Diagnostics(ros, name)
    proc = NodeProcess(name, tmp_path, env={"NUMBA_CACHE_DIR": str(cache)})
    manager = Lifecycle(ros, name)
    try:
        assert manager.state() == State.PRIMARY_STATE_UNCONFIGURED
        answered = time.monotonic()
        diagnostics.wait("warming up", answered, timeout=STARTUP_TIMEOUT)
        assert "kernels ready" not in proc.output()
    finally:
        _stopped(proc)
