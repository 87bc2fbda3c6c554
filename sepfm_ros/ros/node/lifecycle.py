"""The managed (lifecycle) side of the long-running nodes: the kernel warm-up in the background,
``autostart``, and demand (subscribers to the node's outputs).

- Both nodes are rclpy ``LifecycleNode``s with the standard ``lifecycle_msgs`` services
  (``~/change_state``, ``~/get_state``, ...). The process creates the node at once, so it is in
  the graph and answers those services while the estimator's kernels still compile or load
  (:class:`KernelWarmUp`, a thread of its own); configure waits for them.
- ``autostart`` (default true): :func:`start_when_ready` configures and activates the node
  itself once the kernels are ready; with ``autostart:=false`` a lifecycle manager does.
- Demand (:class:`DemandGate`): the sepfm node holds its input subscriptions only while a
  subscriber of its answers exists (or ``always_on`` is set); the gate looks every
  ``DEMAND_POLL_S`` on the node's executor.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from lifecycle_msgs.msg import State
from rclpy._rclpy_pybind11 import RCLError
from rclpy.lifecycle import LifecycleNode, LifecycleState
from rclpy.lifecycle import TransitionCallbackReturn as Ret

DEMAND_POLL_S = 0.2  # how often the demand gate looks at the output subscribers
IDLE = "idle: no subscribers"  # the /diagnostics message of an active node without demand
WARMING_UP = "warming up: compiling or loading the estimator's kernels"
AUTOSTART_POLL_S = 0.1  # how often autostart looks whether the kernels are ready
STATE_NAMES = {
    State.PRIMARY_STATE_UNCONFIGURED: "unconfigured",
    State.PRIMARY_STATE_INACTIVE: "inactive",
    State.PRIMARY_STATE_ACTIVE: "active",
    State.PRIMARY_STATE_FINALIZED: "finalized",
}


class KernelWarmUp:
    """The estimator's kernels compiled (fresh install) or loaded from numba's cache, on a
    thread started by :meth:`start`; :meth:`wait` blocks until they are ready."""

    def __init__(self) -> None:
        self._done = threading.Event()
        self.seconds: float | None = None  #: time the warm-up took, s (None until done)
        self.thread: threading.Thread | None = None

    def start(self) -> KernelWarmUp:
        """Start warming up in a daemon thread (``kernel-warm-up``); returns self."""
        self.thread = threading.Thread(target=self._run, name="kernel-warm-up", daemon=True)
        self.thread.start()
        return self

    def _run(self) -> None:
        try:
            # imported here, on this thread: the estimator's modules (numba, scipy) stay off the
            # start-up path, so the node is in the graph before they load
            from sepfm_ros.pipeline.compiled import warm_up

            self.seconds = warm_up()
        finally:
            self._done.set()

    @property
    def ready(self) -> bool:
        """Whether the kernels are ready."""
        return self._done.is_set()

    @property
    def running(self) -> bool:
        """Whether the warm-up thread is still compiling (it cannot be interrupted)."""
        return self.thread is not None and self.thread.is_alive()

    def wait(self) -> float:
        """Block until the kernels are ready (warming up here when :meth:`start` was not
        called); the warm-up's seconds."""
        if self.thread is None:
            self._run()
        self._done.wait()
        return float(self.seconds or 0.0)


def state_name(node: LifecycleNode) -> str:
    """The node's primary lifecycle state (``unconfigured``, ``inactive``, ...)."""
    state_id, _ = node._state_machine.current_state
    return STATE_NAMES.get(state_id, "transitioning")


def start_when_ready(node: ManagedNode) -> None:
    """``autostart``: configure and activate ``node`` once its kernels are ready (polled on the
    node's executor, so the lifecycle services answer meanwhile)."""
    timer = None

    def poll() -> None:
        if not node.kernels_ready:
            return
        assert timer is not None
        timer.cancel()
        node.destroy_timer(timer)
        if state_name(node) != "unconfigured":
            return  # a manager got there first
        if node.trigger_configure() == Ret.SUCCESS:
            node.trigger_activate()

    timer = node.create_timer(AUTOSTART_POLL_S, poll)


class DemandGate:
    """Calls ``start`` when ``wanted()`` turns true and ``stop`` when it turns false, looking
    every ``DEMAND_POLL_S`` on ``node``'s executor while :meth:`enable`\\ d."""

    def __init__(
        self,
        node: LifecycleNode,
        wanted: Callable[[], bool],
        start: Callable[[], None],
        stop: Callable[[], None],
    ) -> None:
        self._node = node
        self._wanted = wanted
        self._start = start
        self._stop = stop
        self.on = False  #: whether the inputs are held (``start`` called last)
        self._timer = None

    def enable(self) -> None:
        """Start looking (activate); starts the inputs at once when wanted."""
        self._timer = self._node.create_timer(DEMAND_POLL_S, self.poll)
        self.poll()

    def disable(self) -> None:
        """Stop looking and stop the inputs (deactivate)."""
        if self._timer is not None:
            self._timer.cancel()
            self._node.destroy_timer(self._timer)
            self._timer = None
        if self.on:
            self.on = False
            self._stop()

    def poll(self) -> None:
        """Start or stop the inputs when the demand changed."""
        wanted = self._wanted()
        if wanted and not self.on:
            self.on = True
            self._start()
        elif not wanted and self.on:
            self.on = False
            self._stop()


class ManagedNode(LifecycleNode):
    """A lifecycle node whose transitions call four hooks (both nodes derive from it):

    - configure: waits for the kernels (``warm``; None: the node needs none), then
      :meth:`configure_node` (pipeline, outputs, workers);
    - activate: enables the lifecycle publishers, then :meth:`activate_inputs`;
    - deactivate: :meth:`deactivate_inputs` (no input, so no work), then silences the publishers;
    - cleanup: :meth:`release_node`; shutdown (from any state): both.
    """

    def __init__(self, node_name: str, warm: KernelWarmUp | None, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.warm = warm
        self.configured = False
        # rclpy raises from the change_state service on a transition the current state does
        # not have (activate while unconfigured), which would end the executor's spin: refuse it
        service = self._service_change_state
        change = service.callback

        def refuse_invalid(request: Any, response: Any) -> Any:
            try:
                return change(request, response)
            except RCLError as err:
                self.get_logger().warning(
                    f"lifecycle transition {request.transition.id} "
                    f"{request.transition.label!r} refused in state {state_name(self)}: {err}"
                )
                response.success = False
                return response

        service.callback = refuse_invalid

    @property
    def kernels_ready(self) -> bool:
        """Whether the kernels are ready (True for a node that needs none)."""
        return self.warm is None or self.warm.ready

    def configure_node(self, warm_s: float) -> None:
        """Build what the node needs to work (``warm_s``: the kernel warm-up's seconds)."""

    def activate_inputs(self) -> None:
        """Subscribe to the inputs (or start waiting for demand)."""

    def deactivate_inputs(self) -> None:
        """Release the inputs."""

    def release_node(self) -> None:
        """Undo :meth:`configure_node`."""

    def on_configure(self, state: LifecycleState) -> Ret:
        self.configure_node(0.0 if self.warm is None else self.warm.wait())
        self.configured = True
        return Ret.SUCCESS

    def on_activate(self, state: LifecycleState) -> Ret:
        result = super().on_activate(state)
        self.activate_inputs()
        return result

    def on_deactivate(self, state: LifecycleState) -> Ret:
        self.deactivate_inputs()
        self.get_logger().info("deactivated: no input subscriptions, no output")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> Ret:
        self._release()
        return Ret.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> Ret:
        self.deactivate_inputs()
        self._release()
        return Ret.SUCCESS

    def _release(self) -> None:
        if self.configured:
            self.configured = False
            self.release_node()
