"""Two nodes of one name in two namespaces (as the rigs launch starts them) report on
/diagnostics under distinct status names, "<node FQN>: <task>", and take their report period
from ``diagnostic_updater.period``; the old name ``diagnostics_period_s`` still sets it, with a
warning naming the new one."""

from __future__ import annotations

import threading

import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from ros_helpers import RELIABLE, Client, NodeProcess  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

NODE = "sepfm_diag"
RIGS = {"rig_a": "diagnostic_updater.period:=0.4", "rig_b": "diagnostics_period_s:=0.3"}


def test_namespaced_nodes_report_under_their_fully_qualified_names(ros, tmp_path):
    lock = threading.Lock()
    seen: set[str] = set()

    def on_diagnostics(msg: DiagnosticArray) -> None:
        with lock:
            seen.update(status.name for status in msg.status)

    ros.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, RELIABLE)
    procs: dict[str, NodeProcess] = {}
    clients: dict[str, Client] = {}
    try:
        for ns, period in RIGS.items():
            (tmp_path / ns).mkdir()
            procs[ns] = NodeProcess(NODE, tmp_path / ns, "-r", f"__ns:=/{ns}", "-p", period)
        for ns in RIGS:
            inputs = {side: (f"/{ns}/{side}/image_raw", Image) for side in ("left", "right")}
            # the client's node name is the node's FQN without its leading slash
            clients[ns] = Client(ros, f"{ns}/{NODE}", inputs)
            try:
                clients[ns].wait_connected()
            except AssertionError:
                log = procs[ns].output()
                raise AssertionError(f"/{ns}/{NODE} did not come up:\n{log}") from None
        for client in clients.values():
            client.latest_health(after=0.0)  # each node's own report, found by its name
        with lock:
            names = {n for n in seen if NODE in n}
        # on one /diagnostics, each node under its FQN; no name both would share
        assert names == {f"/rig_a/{NODE}: node", f"/rig_b/{NODE}: node"}, names
        assert clients["rig_a"].get_parameter("diagnostic_updater.period") == 0.4
        # the old name sets the new parameter, with a warning that names it
        assert clients["rig_b"].get_parameter("diagnostic_updater.period") == 0.3
    finally:
        for proc in procs.values():
            proc.stop()
    assert "diagnostics_period_s is renamed diagnostic_updater.period" in procs["rig_b"].output()
    assert "renamed" not in procs["rig_a"].output()
