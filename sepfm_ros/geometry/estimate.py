"""The result type of every estimator in :mod:`sepfm_ros.geometry`."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


class StatusCode(IntEnum):
    """What an estimate's status says, as a code (``Estimate.code``); the text says why.

    The values are those of the ``STATUS_*`` constants of ``sepfm_msgs/TwoViewEstimate``.
    """

    OK = 0
    """F exists and is trusted."""
    UNRELIABLE = 1
    """F exists but its robust scale exceeds the threshold (LMedS methods)."""
    DEGENERATE = 2
    """No F, or F not determined by the data: a dominant plane, inliers along one line, no
    motion, too few inliers, every sample degenerate."""
    NOT_SIGNIFICANT = 3
    """F exists but random matches would give its consensus as well (a contrario test)."""
    TOO_FEW_MATCHES = 4
    """Too few matches to estimate F."""
    BAD_INPUT = 5
    """The input could not be used (undecodable image, size change, rejected points)."""
    INTERNAL_ERROR = 6
    """An unexpected error while answering the pair."""


@dataclass
class Estimate:
    """A fundamental-matrix estimate and how it was obtained.

    Attributes:
        F: (3, 3) float64 with ``x2^T F x1 = 0`` (x1 in image 1, x2 in image 2, pixels),
            unit Frobenius norm, rank 2; None when no model was found.
        inliers: (N,) bool, matches within the threshold of F (all False when F is None).
        hypotheses: total models scored (stage 1 + stage 2 + any fallback RANSAC). Each real
            root of the seven-point cubic is one model.
        stage1_hypotheses: line-homography models H_e scored on the line points only.
        stage2_hypotheses: F models scored against all matches.
        line_pair: ((a1, b1, c1), (a2, b2, c2)) the image lines used (``a u + b v + c = 0`` in
            pixels of image 1 and image 2, ``a^2 + b^2 = 1``), or None.
        line_inliers: (M,) int indices of the matches on the line pair that agree with H_e.
        H_e: (2, 2) the epipolar line homography of stage 1 (refined on the line inliers), or
            None; it maps (alpha, beta) = (1 - t, t) of a point c1 + t (c2 - c1) on line 1 to
            those of its correspondence on line 2, up to scale.
        control_points: ((2, 2), (2, 2)) the control points c1, c2 of line 1 and of line 2 in
            pixels (where the lines meet the image borders), or None.
        samples: minimal samples drawn, every stage together (stage 1's 3-point samples,
            stage 2, fallback); at most the ``max_samples`` option.
        fallback: True when standard RANSAC ran because no usable line pair was found.
        line_search_skipped: True when the separable method skipped its line search (the
            paper's escape, option ``line_search_escape``): the inlier ratio its first PROSAC
            samples showed made standard RANSAC the cheaper way, and the estimate is standard
            RANSAC's (``fallback`` stays False: no line pair was looked for). When that answer
            is degenerate (a dominant plane shows the probe a high inlier ratio) or missing,
            the method runs again with its line search, and this is False; the first try's
            hypotheses and samples count.
        unfixed_lead: True when stage 2's best model came from its arm without fixed points
            (``EstimatorOptions.unfixed_share``), not from a line pair's; the line-pair fields
            are then None.
        periodic_line_pairs: line pairs whose H_e support was found periodic (a row of equally
            spaced points, ``EstimatorOptions.periodic_check``) and whose arms joined stage 2
            after the others.
        status: "ok", or a short reason when F is None or unreliable (e.g. "degenerate: ...").
        code: the status as a :class:`StatusCode` (set together with ``status``, see
            :meth:`set_status`).
        method: the method name that produced this estimate.
        timings_ms: milliseconds per stage ("lines", "stage1", "stage2", "refine", "total").
        scale: the LMedS methods' robust scale sigma (px of symmetric epipolar distance) of F,
            1.4826 (1 + 5 / (N - p)) sqrt(median d^2); their inliers are d < 2.5 sigma. None
            for the other methods.
        log10_nfa: log10 of the number of false alarms of the final inliers (Moisan and
            Stival's a contrario test, :mod:`sepfm_ros.geometry.fundamental.significance`):
            below 0, a
            consensus that random matches do not give. None when F had fewer than 8 inliers.
    """

    F: np.ndarray | None
    inliers: np.ndarray
    hypotheses: int = 0
    stage1_hypotheses: int = 0
    stage2_hypotheses: int = 0
    line_pair: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    line_inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    H_e: np.ndarray | None = None
    control_points: tuple[np.ndarray, np.ndarray] | None = None
    samples: int = 0
    fallback: bool = False
    line_search_skipped: bool = False
    unfixed_lead: bool = False
    periodic_line_pairs: int = 0
    status: str = "ok"
    code: StatusCode = StatusCode.OK
    method: str = ""
    timings_ms: dict[str, float] = field(default_factory=dict)
    scale: float | None = None
    log10_nfa: float | None = None

    def set_status(self, code: StatusCode, text: str) -> None:
        """Set the status code and its text together."""
        self.code = StatusCode(code)
        self.status = text

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))

    @property
    def ok(self) -> bool:
        """True when F exists and the status is not a failure/degeneracy."""
        return self.F is not None and self.code == StatusCode.OK
