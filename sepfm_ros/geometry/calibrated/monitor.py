"""The stereo calibration check's decision: OK / WARN / ERROR over a sliding window of pairs.

:class:`CalibrationMonitor` takes each pair's
:class:`~sepfm_ros.geometry.calibrated.calibration_check.PairCheck` and decides on medians over
the window, so one bad pair does not alarm. Levels are ``diagnostic_msgs/DiagnosticStatus``
levels (OK 0, WARN 1, ERROR 2, STALE 3 while the window has too few usable pairs). A light
module (numpy only): parameter tables use :class:`MonitorConfig` without loading the fits.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}


class PairCheck(Protocol):
    """What the monitor reads of a pair's check
    (:class:`~sepfm_ros.geometry.calibrated.calibration_check.PairCheck`)."""

    @property
    def n_inliers(self) -> int: ...
    @property
    def epipolar_median_px(self) -> float: ...
    @property
    def epipolar_p90_px(self) -> float: ...
    @property
    def rotation_error_deg(self) -> float: ...
    @property
    def rotation_axes_deg(self) -> np.ndarray: ...
    @property
    def usable(self) -> bool: ...


@dataclass(frozen=True)
class MonitorConfig:
    """Parameters of :class:`CalibrationMonitor` (node parameters ``calibration_check.*``).

    Attributes:
        window: pairs in the sliding window (>= 1).
        min_pairs: usable pairs needed in the window before a decision (else STALE).
        min_inliers: inliers a pair needs to be usable.
        warn_epipolar_px, error_epipolar_px: thresholds on the window median of the pairs'
            median epipolar error (px).
        warn_rotation_deg, error_rotation_deg: thresholds on the window median of the pairs'
            rotation error (degrees).
    """

    window: int = 10
    min_pairs: int = 5
    min_inliers: int = 30
    warn_epipolar_px: float = 1.0
    error_epipolar_px: float = 3.0
    warn_rotation_deg: float = 0.07
    error_rotation_deg: float = 0.5

    def __post_init__(self) -> None:
        errors = []
        if not int(self.window) >= 1:
            errors.append(f"window must be >= 1, got {self.window}")
        if not 1 <= int(self.min_pairs) <= int(self.window):
            errors.append(f"min_pairs must be in [1, window], got {self.min_pairs}")
        if int(self.min_inliers) < 5:
            errors.append(f"min_inliers must be >= 5, got {self.min_inliers}")
        for warn, err, unit in (
            (self.warn_epipolar_px, self.error_epipolar_px, "epipolar_px"),
            (self.warn_rotation_deg, self.error_rotation_deg, "rotation_deg"),
        ):
            if not 0 < float(warn) <= float(err):
                errors.append(f"need 0 < warn_{unit} <= error_{unit}, got {warn}, {err}")
        if errors:
            raise ValueError("invalid calibration check config: " + "; ".join(errors))


@dataclass(frozen=True)
class CalibrationStatus:
    """The monitor's decision after a pair.

    Attributes:
        level: OK, WARN, ERROR or STALE (diagnostic_msgs levels 0..3).
        message: one line for humans.
        values: figures (str -> float/int) for the diagnostic's key/values.
    """

    level: int
    message: str
    values: dict[str, float | int] = field(default_factory=dict)

    @property
    def level_name(self) -> str:
        return LEVEL_NAMES[self.level]


class CalibrationMonitor:
    """Sliding-window OK / WARN / ERROR decision over :class:`PairCheck` results."""

    def __init__(self, config: MonitorConfig | None = None) -> None:
        self.config = config or MonitorConfig()
        self._window: deque[PairCheck] = deque(maxlen=int(self.config.window))

    def reset(self) -> None:
        """Forget the window (e.g. after a new calibration arrived)."""
        self._window.clear()

    def update(self, check: PairCheck) -> CalibrationStatus:
        """Add one pair's check and decide."""
        self._window.append(check)
        return self.status()

    def status(self) -> CalibrationStatus:
        """The decision on the current window."""
        cfg = self.config
        usable = [c for c in self._window if c.usable]
        values: dict[str, float | int] = {
            "pairs_in_window": len(self._window),
            "usable_pairs": len(usable),
        }
        last = self._window[-1] if self._window else None
        if last is not None:
            values.update(
                last_inliers=last.n_inliers,
                last_epipolar_median_px=last.epipolar_median_px,
                last_epipolar_p90_px=last.epipolar_p90_px,
                last_rotation_error_deg=last.rotation_error_deg,
            )
        if len(usable) < cfg.min_pairs:
            return CalibrationStatus(
                STALE,
                f"calibration not checked: {len(usable)} of {cfg.min_pairs} pairs with at least "
                f"{cfg.min_inliers} inliers in the last {len(self._window)}",
                values,
            )
        epi = float(np.median([c.epipolar_median_px for c in usable]))
        p90 = float(np.median([c.epipolar_p90_px for c in usable]))
        rot = float(np.median([c.rotation_error_deg for c in usable]))
        axes = np.median([c.rotation_axes_deg for c in usable], axis=0)
        values.update(
            epipolar_median_px=epi,
            epipolar_p90_px=p90,
            rotation_error_deg=rot,
            rotation_x_deg=float(axes[0]),
            rotation_y_deg=float(axes[1]),
            rotation_z_deg=float(axes[2]),
        )
        figures = f"epipolar error {epi:.2f} px (p90 {p90:.2f}), rotation {rot:.3f} deg"
        if epi > cfg.error_epipolar_px or rot > cfg.error_rotation_deg:
            return CalibrationStatus(ERROR, f"stereo calibration is off: {figures}", values)
        if epi > cfg.warn_epipolar_px or rot > cfg.warn_rotation_deg:
            return CalibrationStatus(WARN, f"stereo calibration drifting: {figures}", values)
        return CalibrationStatus(OK, f"stereo calibration holds: {figures}", values)
