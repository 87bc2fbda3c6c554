"""diagnostic_msgs helpers: key/value lists, a status from named values, the array, and the
names of statuses.

Status names follow diagnostic_updater's ``"<node>: <task>"``, with the node's fully qualified
name (``/rig_a/sepfm: node``) where diagnostic_updater has the bare node name: two nodes of the
same name in different namespaces (the rigs launch) then report under different names.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from sepfm_ros.ros.msgs.headers import copy_header


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return str(value)


def key_values(values: Mapping[str, Any]) -> list[KeyValue]:
    """name -> value as diagnostic_msgs/KeyValue (floats with 6 significant digits)."""
    return [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]


def status_name(node_fqn: str, task: str) -> str:
    """The name of a status of task ``task`` of the node ``node_fqn`` (fully qualified, e.g.
    ``/rig_a/sepfm``): ``"/rig_a/sepfm: calibration"``."""
    return f"{node_fqn}: {task}"


def health_status(
    name: str, level: bytes, message: str, values: Mapping[str, Any], hardware_id: str = ""
) -> DiagnosticStatus:
    """A diagnostic_msgs/DiagnosticStatus; ``level`` is DiagnosticStatus.OK/WARN/ERROR/STALE."""
    return DiagnosticStatus(
        level=level,
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=key_values(values),
    )


def diagnostic_array(header: Header, statuses: list[DiagnosticStatus]) -> DiagnosticArray:
    """Wrap statuses into a diagnostic_msgs/DiagnosticArray with ``header`` (copied)."""
    return DiagnosticArray(header=copy_header(header), status=statuses)


def status_values(status: DiagnosticStatus) -> dict[str, str]:
    """The values of a DiagnosticStatus as a dict (for readers and tests)."""
    return {kv.key: kv.value for kv in status.values}
