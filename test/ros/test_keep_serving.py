"""``ros/keep_serving``: a guarded callback's exception is counted and the executor keeps
serving; recurring problems are logged once per period per kind. On a real rclpy node."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402

from sepfm_ros.ros.node.keep_serving import ThrottledLog, guarded  # noqa: E402

TIMEOUT = 60.0  # s; the machine is shared


class FlakyNode(Node):
    """A timer callback that raises on every odd call."""

    def __init__(self, context: Context) -> None:
        super().__init__("keep_serving_test", context=context)
        self.calls = 0
        self.errors: list[tuple[str, str]] = []
        self.create_timer(0.01, self._tick)

    def internal_error(self, kind: str, text: str) -> None:
        self.errors.append((kind, text))

    @guarded
    def _tick(self) -> None:
        self.calls += 1
        if self.calls % 2:
            raise ValueError(f"bad tick {self.calls}")


@pytest.fixture
def context() -> Iterator[Context]:
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        rclpy.shutdown(context=ctx)


def test_a_guarded_callback_reports_its_exception_and_the_executor_keeps_serving(
    context: Context,
) -> None:
    node = FlakyNode(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + TIMEOUT
        while node.calls < 6 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)  # an unguarded raise would come out here
    finally:
        executor.shutdown()
        node.destroy_node()
    assert node.calls >= 6
    assert len(node.errors) == (node.calls + 1) // 2
    assert {kind for kind, _ in node.errors} == {"internal_ValueError"}
    first = node.errors[0][1]
    assert first.startswith("_tick: Traceback") and "ValueError: bad tick 1" in first


def test_a_recurring_problem_is_logged_once_per_period_with_the_count_held_back(
    context: Context, capfd: pytest.CaptureFixture[str]
) -> None:
    node = Node("throttled_log_test", context=context)
    try:
        log = ThrottledLog(node, period_s=3600.0)
        log.log("decode", "first decode failure")
        log.log("decode", "second decode failure")  # held back
        log.log("lost", "samples lost", error=False)
        err = capfd.readouterr().err
    finally:
        node.destroy_node()
    assert "first decode failure" in err and "second decode failure" not in err
    assert "[ERROR]" in err.split("first decode failure")[0].splitlines()[-1]
    assert "[WARN]" in err.split("samples lost")[0].splitlines()[-1]
    assert "logged at most every 3600 s" in err
