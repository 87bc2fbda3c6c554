"""Builders (and readers) of the node's output messages. Pure functions on rclpy message types.

Shared by the live node, offline bag processing and bag recording (serialize the results with
``rclpy.serialization.serialize_message`` to write them into a bag).

- :func:`fundamental_to_image`: F as a 3x3 ``64FC1`` sensor_msgs/Image (row-major).
- :func:`matches_to_pointcloud2`: all putative matches as sensor_msgs/PointCloud2 with float32
  fields u_a, v_a, u_b, v_b, error (symmetric epipolar distance, px) and uint8 inlier, on_line.
- :func:`estimate_info`: diagnostic_msgs/DiagnosticArray describing one estimate.
- :func:`failure_info`: the same for a pair that could not be processed (bad input), ERROR level.
- :func:`health_status`: a diagnostic_msgs/DiagnosticStatus from name/value pairs.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from sensor_msgs.msg import Image, PointCloud2, PointField
from std_msgs.msg import Header

from sepfm_ros.pipeline.pipeline import PipelineResult

ESTIMATE_STATUS_NAME = "sepfm: estimate"

# Layout of one point of ~/matches (22 bytes of fields, padded to 24).
MATCH_FIELDS: tuple[tuple[str, int, int], ...] = (
    ("u_a", 0, PointField.FLOAT32),
    ("v_a", 4, PointField.FLOAT32),
    ("u_b", 8, PointField.FLOAT32),
    ("v_b", 12, PointField.FLOAT32),
    ("error", 16, PointField.FLOAT32),
    ("inlier", 20, PointField.UINT8),
    ("on_line", 21, PointField.UINT8),
)
MATCH_POINT_STEP = 24
MATCH_DTYPE = np.dtype(
    {
        "names": [f[0] for f in MATCH_FIELDS],
        "formats": ["<f4"] * 5 + ["u1", "u1"],
        "offsets": [f[1] for f in MATCH_FIELDS],
        "itemsize": MATCH_POINT_STEP,
    }
)


def stamp_ns(stamp: Time) -> int:
    """builtin_interfaces/Time (or any object with ``sec`` and ``nanosec``) -> integer ns.

    The package's one stamp conversion (serialized CDR headers: ``bags.types.header_stamp_ns``).
    """
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def camera_info_topic(image_topic: str) -> str:
    """The ``camera_info`` topic beside an image topic, as image_transport pairs them:
    ``/left/image_raw`` (or ``/left/image_raw/compressed``) -> ``/left/camera_info``."""
    base = image_topic.removesuffix("/compressed")
    parent = base.rsplit("/", 1)[0] if "/" in base else ""
    return parent + "/camera_info"


def copy_header(header: Header) -> Header:
    """An independent copy of a std_msgs/Header."""
    return Header(
        stamp=Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec)),
        frame_id=str(header.frame_id),
    )


def fundamental_to_image(F: np.ndarray, header: Header) -> Image:
    """F (3, 3) -> sensor_msgs/Image: 64FC1, height = width = 3, row-major, native order."""
    F = np.ascontiguousarray(np.asarray(F, dtype=np.float64))
    if F.shape != (3, 3) or not np.all(np.isfinite(F)):
        raise ValueError(f"F must be a finite 3x3 matrix, got shape {F.shape}")
    return Image(
        header=copy_header(header),
        height=3,
        width=3,
        encoding="64FC1",
        is_bigendian=int(sys.byteorder == "big"),
        step=24,
        data=F.tobytes(),
    )


def fundamental_from_image(msg: Image) -> np.ndarray:
    """Inverse of :func:`fundamental_to_image`: a 64FC1 3x3 Image -> F (3, 3) float64."""
    if msg.encoding != "64FC1" or (msg.height, msg.width) != (3, 3) or msg.step < 24:
        raise ValueError(
            f"expected a 3x3 64FC1 image, got {msg.width}x{msg.height} {msg.encoding!r}"
        )
    order = ">" if msg.is_bigendian else "<"
    raw = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    if raw.size < 3 * msg.step:
        raise ValueError(f"F image data too short: {raw.size} B < {3 * msg.step} B")
    rows = raw[: 3 * msg.step].reshape(3, msg.step)[:, :24]
    return rows.view(np.dtype(order + "f8")).reshape(3, 3).astype(np.float64)


def matches_to_pointcloud2(
    header: Header,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    errors: np.ndarray,
    inliers: np.ndarray,
    on_line: np.ndarray,
) -> PointCloud2:
    """Matches -> sensor_msgs/PointCloud2 (height 1, width N, little-endian, dense).

    Args:
        pts_a, pts_b: (N, 2) pixel coordinates in image a / image b.
        errors: (N,) symmetric epipolar distance in px (NaN when there is no F).
        inliers, on_line: (N,) bool.
    """
    n = int(np.asarray(pts_a).shape[0])
    cloud = np.zeros(n, dtype=MATCH_DTYPE)
    if n:
        cloud["u_a"], cloud["v_a"] = pts_a[:, 0], pts_a[:, 1]
        cloud["u_b"], cloud["v_b"] = pts_b[:, 0], pts_b[:, 1]
        cloud["error"] = errors
        cloud["inlier"] = np.asarray(inliers, dtype=bool)
        cloud["on_line"] = np.asarray(on_line, dtype=bool)
    return PointCloud2(
        header=copy_header(header),
        height=1,
        width=n,
        fields=[
            PointField(name=nm, offset=off, datatype=dt, count=1) for nm, off, dt in MATCH_FIELDS
        ],
        is_bigendian=False,
        point_step=MATCH_POINT_STEP,
        row_step=MATCH_POINT_STEP * n,
        data=cloud.tobytes(),
        is_dense=True,
    )


def result_to_pointcloud2(result: PipelineResult, header: Header) -> PointCloud2:
    """The matches of a pipeline result as ~/matches."""
    m = result.matches
    return matches_to_pointcloud2(
        header, m.pts_a, m.pts_b, result.errors, result.estimate.inliers, result.on_line
    )


def matches_from_pointcloud2(msg: PointCloud2) -> np.ndarray:
    """Inverse of :func:`matches_to_pointcloud2`: a structured (N,) array of MATCH_DTYPE."""
    names = [f.name for f in msg.fields]
    if names != [f[0] for f in MATCH_FIELDS] or msg.point_step != MATCH_POINT_STEP:
        raise ValueError(f"not a ~/matches cloud: fields {names}, point_step {msg.point_step}")
    raw = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    n = int(msg.width) * int(msg.height)
    return raw[: n * MATCH_POINT_STEP].view(MATCH_DTYPE).copy()


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return str(value)


def key_values(values: Mapping[str, Any]) -> list[KeyValue]:
    """name -> value as diagnostic_msgs/KeyValue (floats with 6 significant digits)."""
    return [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]


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


def _line_str(line: Any) -> str:
    return " ".join(f"{float(c):.6g}" for c in line)


def estimate_values(
    result: PipelineResult,
    stamp_a: Time,
    stamp_b: Time,
    features: str,
    extra_timings_ms: Mapping[str, float] | None = None,
    extra_values: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The key/value pairs of ~/estimate_info for one pipeline result (see estimate_info)."""
    est = result.estimate
    values: dict[str, Any] = {
        "stamp_a": f"{int(stamp_a.sec)}.{int(stamp_a.nanosec):09d}",
        "stamp_b": f"{int(stamp_b.sec)}.{int(stamp_b.nanosec):09d}",
        "method": est.method,
        "features": features,
        "status": est.status,
        "matches": len(result.matches),
        "inliers": est.num_inliers,
        "hypotheses": est.hypotheses,
        "stage1_hypotheses": est.stage1_hypotheses,
        "stage2_hypotheses": est.stage2_hypotheses,
        "fallback": est.fallback,
        "unfixed_lead": est.unfixed_lead,
        "log10_nfa": "none" if est.log10_nfa is None else float(est.log10_nfa),
        "line_inliers": len(est.line_inliers),
        "line_a": _line_str(est.line_pair[0]) if est.line_pair is not None else "none",
        "line_b": _line_str(est.line_pair[1]) if est.line_pair is not None else "none",
        "size_a": f"{result.size_a[0]}x{result.size_a[1]}",
        "size_b": f"{result.size_b[0]}x{result.size_b[1]}",
        "coordinates": result.coordinates,
    }
    values.update(extra_values or {})
    timings = dict(result.timings_ms)
    timings.update(extra_timings_ms or {})
    for stage, ms in timings.items():
        values[f"ms_{stage}"] = float(ms)
    return values


def estimate_info(
    result: PipelineResult,
    header: Header,
    stamp_a: Time,
    stamp_b: Time,
    features: str,
    extra_timings_ms: Mapping[str, float] | None = None,
    node_name: str = "sepfm",
    extra_values: Mapping[str, Any] | None = None,
) -> DiagnosticArray:
    """~/estimate_info: one DiagnosticStatus (name "sepfm: estimate") describing the estimate.

    Level OK with message "ok" when F was estimated, WARN with the estimator's reason otherwise.
    Values: stamp_a, stamp_b (sec.nanosec), method, features, status, matches, inliers,
    hypotheses, stage1_hypotheses, stage2_hypotheses, fallback, unfixed_lead, log10_nfa (the
    a contrario significance of the inliers, "none" without one), line_inliers, line_a, line_b
    ("a b c" of a u + b v + c = 0, or "none"), size_a, size_b, coordinates (the pixels of F and
    the matches: "image", or "undistorted" pixels of K with camera_info), ``extra_values`` (e.g.
    the relative pose) and ms_<stage> per timing stage.
    """
    ok = result.ok
    status = health_status(
        ESTIMATE_STATUS_NAME,
        DiagnosticStatus.OK if ok else DiagnosticStatus.WARN,
        "ok" if ok else result.estimate.status,
        estimate_values(result, stamp_a, stamp_b, features, extra_timings_ms, extra_values),
        hardware_id=node_name,
    )
    return diagnostic_array(header, [status])


def failure_info(
    header: Header,
    stamp_a: Time,
    stamp_b: Time,
    reason: str,
    kind: str,
    features: str,
    method: str,
    node_name: str = "sepfm",
) -> DiagnosticArray:
    """~/estimate_info for a pair that never reached the estimator (e.g. an undecodable image).

    Level ERROR, message ``reason``; the values of :func:`estimate_info` with zero counts, plus
    ``error_kind`` (the bad-input kind counted in /diagnostics). No F and no matches are published
    for such a pair, so every pair the node took still gets exactly one answer.
    """
    values: dict[str, Any] = {
        "stamp_a": f"{int(stamp_a.sec)}.{int(stamp_a.nanosec):09d}",
        "stamp_b": f"{int(stamp_b.sec)}.{int(stamp_b.nanosec):09d}",
        "method": method,
        "features": features,
        "status": f"bad input ({kind}): {reason}",
        "error_kind": kind,
        "matches": 0,
        "inliers": 0,
        "hypotheses": 0,
        "stage1_hypotheses": 0,
        "stage2_hypotheses": 0,
        "fallback": False,
        "unfixed_lead": False,
        "log10_nfa": "none",
        "line_inliers": 0,
        "line_a": "none",
        "line_b": "none",
    }
    status = health_status(
        ESTIMATE_STATUS_NAME,
        DiagnosticStatus.ERROR,
        values["status"],
        values,
        hardware_id=node_name,
    )
    return diagnostic_array(header, [status])


def status_values(status: DiagnosticStatus) -> dict[str, str]:
    """The values of a DiagnosticStatus as a dict (for readers and tests)."""
    return {kv.key: kv.value for kv in status.values}
