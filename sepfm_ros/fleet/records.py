"""What the audit's tasks return and the driver writes: pair records, a bag's description, the
slice tasks, failures, and a bag's row of the fleet table (:func:`bag_row`).

Everything here is plain data (picklable, no ROS types), so it travels between the engine's
processes and machines unchanged.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass, field, fields
from datetime import datetime, timezone
from typing import Any

import numpy as np

FLAG_LEVELS = ("WARN", "ERROR")
LEVEL_RANK = {"": -1, "STALE": 0, "OK": 1, "WARN": 2, "ERROR": 3}


@dataclass(frozen=True)
class PairRecord:
    """One pair's answer, as the audit keeps it.

    Attributes:
        stamp_ns: the pair's header stamp (left camera in stereo, newer frame in motion), ns.
        log_time_ns: the bag's log time of the message that completed the pair, ns.
        status: the estimator's status text ("ok", "degenerate: ...", "skipped: ...").
        has_f: an F was published for the pair (the node's rule: ok, or unreliable with
            ``publish_unreliable``).
        matches, inliers: counts.
        inlier_error_px: median epipolar error of the inliers under F, px (NaN without F).
        rotation_error_deg: this pair's rotation against the calibration, degrees (NaN when
            the pair had too few inliers or the bag has no calibrated stereo).
        epipolar_median_px: this pair's median epipolar error against the calibration, px.
        window_rotation_deg, window_rotation_x_deg: the calibration check's window medians
            after this pair (total and about the camera x axis), degrees.
        level: the calibration check's decision after this pair (OK, WARN, ERROR, STALE; ""
            without a calibration check).
        correction_pitch_deg, correction_yaw_deg, correction_roll_deg: the rig's corrected
            rotation after this pair, about camera b's x (pitch), y (yaw) and z (roll) optical
            axes, degrees (NaN without a correction; see
            :mod:`sepfm_ros.geometry.calibrated.correction`).
        correction_pitch_ci95_deg, ...: half-widths of their 95 % intervals, degrees.
        correction_yaw_determined: the data determined yaw (else it is the calibration's);
            None without a correction.
        correction_pairs: pairs the correction was estimated from (None without one).
        correction_reason: why a flagged pair has no correction ("" otherwise).
    """

    stamp_ns: int
    log_time_ns: int
    status: str
    has_f: bool
    matches: int
    inliers: int
    inlier_error_px: float = math.nan
    rotation_error_deg: float = math.nan
    epipolar_median_px: float = math.nan
    window_rotation_deg: float = math.nan
    window_rotation_x_deg: float = math.nan
    level: str = ""
    correction_pitch_deg: float = math.nan
    correction_yaw_deg: float = math.nan
    correction_roll_deg: float = math.nan
    correction_pitch_ci95_deg: float = math.nan
    correction_yaw_ci95_deg: float = math.nan
    correction_roll_ci95_deg: float = math.nan
    correction_yaw_determined: bool | None = None
    correction_pairs: int | None = None
    correction_reason: str = ""


#: the correction's columns, the same in pairs.csv and bags.csv
CORRECTION_FIELDS = (
    "correction_pitch_deg",
    "correction_yaw_deg",
    "correction_roll_deg",
    "correction_pitch_ci95_deg",
    "correction_yaw_ci95_deg",
    "correction_roll_ci95_deg",
    "correction_yaw_determined",
    "correction_pairs",
    "correction_reason",
)

PAIR_FIELDS = [f.name for f in fields(PairRecord)]


@dataclass(frozen=True)
class InputChoice:
    """The user's choice of input topics (None: picked from each bag as ``process`` picks
    them) and whether ``sync_slop_s`` was set (else the slop follows the frame period)."""

    mode: str | None = None
    left: str | None = None
    right: str | None = None
    image: str | None = None
    slop_given: bool = False


@dataclass(frozen=True)
class CameraIdentity:
    """What a bag says about one camera: frame id, image size, K, D, P (from camera_info when
    the bag has it, else only the image's frame id and size)."""

    topic: str
    frame_id: str
    size: tuple[int, int]
    K: tuple[float, ...] = ()
    D: tuple[float, ...] = ()
    P: tuple[float, ...] = ()


@dataclass(frozen=True)
class BagInfo:
    """A bag as the audit plans it (:func:`sepfm_ros.ros.offline.audit_slices.inspect_bag`).

    Attributes:
        bag: the bag's path (as the workers see it).
        mode: "stereo" or "motion"; topics: the input image topics.
        calibrated: stereo with camera_info on both cameras (the calibration check runs).
        cameras: what the bag says about each input camera (the rig's identity).
        start_ns, end_ns: log time span of the bag, ns.
        period_ns: median step of the first camera's header stamps, ns.
        slop_ns: the stereo pairing slop, ns (None in motion).
        expected_pairs: pairs a regular bag gives (for the progress bar).
        frames: messages per input topic.
    """

    bag: str
    mode: str
    topics: tuple[str, ...]
    calibrated: bool
    cameras: tuple[CameraIdentity, ...]
    start_ns: int
    end_ns: int
    period_ns: int
    slop_ns: int | None
    expected_pairs: int
    frames: tuple[int, ...]


@dataclass(frozen=True)
class SliceTask:
    """One slice of a bag: the pairs completed at log times in [t0_ns, t1_ns), computed after
    reading from ``read_from_ns`` so that the pairing and the calibration check's window hold
    what the unsliced run holds at t0 (see :mod:`sepfm_ros.fleet.slices`)."""

    info: BagInfo
    index: int
    count: int
    t0_ns: int
    t1_ns: int
    read_from_ns: int
    params: dict[str, Any]


@dataclass(frozen=True)
class SliceResult:
    """The pairs a slice owns, in order, and how many earlier pairs it ran to warm up."""

    index: int
    pairs: list[PairRecord]
    warm_pairs: int = 0


@dataclass(frozen=True)
class TaskFailure:
    """A task that could not do its work on a bag: the reason, meant for people."""

    reason: str


@dataclass
class Thresholds:
    """The calibration check's warning threshold the report marks drift with, degrees."""

    warn_rotation_deg: float = 0.07
    error_rotation_deg: float = 0.5


def _iso(stamp_ns: int | None) -> str:
    if stamp_ns is None:
        return ""
    return datetime.fromtimestamp(stamp_ns / 1e9, timezone.utc).isoformat(timespec="milliseconds")


def _median(values: list[float]) -> float:
    finite = [v for v in values if not math.isnan(v)]
    return float(np.median(finite)) if finite else math.nan


def status_kind(status: str) -> str:
    """The kind of an estimator status text: "ok", "degenerate", "bad input", ..."""
    return status.split(":", 1)[0].split("(", 1)[0].strip() or "unknown"


def drift_start(pairs: list[PairRecord], first_flag: int, warn_deg: float) -> int:
    """Index of the first pair of the drift that raised the flag at ``first_flag``: going back
    from the flag over pairs whose rotation exceeds ``warn_deg`` (pairs without a measure are
    passed over), the earliest one; ``first_flag`` itself when its pair is not over."""
    start = first_flag
    for k in range(first_flag, -1, -1):
        r = pairs[k].rotation_error_deg
        if math.isnan(r):
            continue
        if r <= warn_deg:
            break
        start = k
    return start


@dataclass
class BagRow:
    """One row of the fleet table (``bags.csv``): a bag of a rig and its answer.

    The ``correction_*`` columns are those of the bag's last corrected pair when the bag was
    flagged (WARN or ERROR; :func:`bag_correction`), empty otherwise.
    """

    rig_id: str
    rig: str
    rig_label: str
    bag: str
    state: str  # done | failed
    reason: str = ""
    start_utc: str = ""
    end_utc: str = ""
    duration_s: float = math.nan
    mode: str = ""
    topics: str = ""
    calibrated: bool = False
    pairs: int = 0
    pairs_with_f: int = 0
    share_with_f: float = math.nan
    median_inliers: float = math.nan
    median_inlier_error_px: float = math.nan
    status_counts: str = ""
    rotation_drift_deg: float = math.nan
    max_window_rotation_deg: float = math.nan
    worst_level: str = ""
    first_flagged_utc: str = ""
    first_flagged_s: float = math.nan
    drift_start_utc: str = ""
    drift_start_s: float = math.nan
    correction_pitch_deg: float = math.nan
    correction_yaw_deg: float = math.nan
    correction_roll_deg: float = math.nan
    correction_pitch_ci95_deg: float = math.nan
    correction_yaw_ci95_deg: float = math.nan
    correction_roll_ci95_deg: float = math.nan
    correction_yaw_determined: bool | None = None
    correction_pairs: int | None = None
    correction_reason: str = ""
    slices: int = 0
    key: str = ""
    extra: dict[str, Any] = field(default_factory=dict, repr=False)

    def as_csv(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("extra")
        return d


ROW_FIELDS = [f.name for f in fields(BagRow) if f.name != "extra"]


def bag_row(
    info: BagInfo,
    pairs: list[PairRecord],
    rig_id: str,
    rig: str,
    rig_label: str,
    key: str,
    slices: int,
    thresholds: Thresholds,
) -> BagRow:
    """The fleet table's row of a bag whose pairs are ``pairs`` (in order, every slice's)."""
    row = BagRow(rig_id, rig, rig_label, info.bag, "done", key=key, slices=slices)
    row.start_utc, row.end_utc = _iso(info.start_ns), _iso(info.end_ns)
    row.duration_s = (info.end_ns - info.start_ns) / 1e9
    row.mode, row.topics, row.calibrated = info.mode, " ".join(info.topics), info.calibrated
    row.pairs = len(pairs)
    if not pairs:
        row.reason = "no pairs answered"
        return row
    row.pairs_with_f = sum(p.has_f for p in pairs)
    row.share_with_f = row.pairs_with_f / len(pairs)
    row.median_inliers = float(np.median([p.inliers for p in pairs]))
    row.median_inlier_error_px = _median([p.inlier_error_px for p in pairs])
    counts = Counter(status_kind(p.status) for p in pairs)
    row.status_counts = "; ".join(f"{k}: {n}" for k, n in counts.most_common())
    if info.calibrated:
        row.rotation_drift_deg = _median([p.rotation_error_deg for p in pairs])
        window = [p.window_rotation_deg for p in pairs if not math.isnan(p.window_rotation_deg)]
        row.max_window_rotation_deg = max(window) if window else math.nan
        row.worst_level = max((p.level for p in pairs), key=lambda lv: LEVEL_RANK.get(lv, -1))
        flagged = [k for k, p in enumerate(pairs) if p.level in FLAG_LEVELS]
        if flagged:
            first = flagged[0]
            start = drift_start(pairs, first, thresholds.warn_rotation_deg)
            row.first_flagged_utc = _iso(pairs[first].stamp_ns)
            row.first_flagged_s = (pairs[first].log_time_ns - info.start_ns) / 1e9
            row.drift_start_utc = _iso(pairs[start].stamp_ns)
            row.drift_start_s = (pairs[start].log_time_ns - info.start_ns) / 1e9
            for name, value in bag_correction(pairs).items():
                setattr(row, name, value)
    return row


def bag_correction(pairs: list[PairRecord]) -> dict[str, Any]:
    """The correction columns of a flagged bag: those of its last pair with a correction
    (the estimate from the most pairs, at the end of the drift), else the reason its last
    flagged pair gave (``correction_reason``; the rotation columns stay empty)."""
    corrected = [p for p in pairs if p.correction_pairs]
    if corrected:
        return {name: getattr(corrected[-1], name) for name in CORRECTION_FIELDS}
    flagged = [p for p in pairs if p.level in FLAG_LEVELS]
    reason = flagged[-1].correction_reason if flagged else ""
    return {"correction_reason": reason or "no correction estimated"}


def failed_row(
    bag: str, reason: str, key: str, rig_id: str = "", rig: str = "", rig_label: str = ""
) -> BagRow:
    """The row of a bag the audit could not answer, with the reason."""
    return BagRow(rig_id or "unknown", rig or "unknown", rig_label, bag, "failed", reason, key=key)
