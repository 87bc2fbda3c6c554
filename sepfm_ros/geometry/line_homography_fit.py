"""Stage 1 of the separable method: RANSAC for the epipolar line homography H_e on a line pair.

Points on the line pair are written in control-point coordinates (parameter t along the segment
between the two control points, i.e. (alpha, beta) = (1 - t, t)); H_e is found by sampling 3
correspondences (minimal solver) with threshold T1 (px at the working resolution) on the
symmetric transfer error along the lines, and adaptive termination F(3, r).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sepfm_ros.geometry.fundamental_problem import score_distances
from sepfm_ros.geometry.line_pairs import LinePair, control_points, line_parameter
from sepfm_ros.geometry.ransac import run_ransac
from sepfm_ros.geometry.solvers.line_homography import (
    inverse,
    line_homography_3pt,
    line_homography_lsq,
    transfer,
)


@dataclass(frozen=True)
class LineHomographyFit:
    """Result of stage 1 on one line pair.

    H: (2, 2) H_e refined on all line inliers (maps t on line 1 to t' on line 2 via (1-t, t)).
    ctrl1, ctrl2: (2, 2) control points in pixels. inliers: indices (into all matches) of the
    line correspondences that agree with H_e. hypotheses: H_e models scored. orientation:
    1 for the first control-point orientation, 2 for the swapped one.
    """

    pair: LinePair
    H: np.ndarray
    ctrl1: np.ndarray
    ctrl2: np.ndarray
    inliers: np.ndarray
    hypotheses: int
    orientation: int

    def map_points(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact correspondences synthesised from H_e at parameters t (K,) -> two (K, 2) arrays."""
        tp = transfer(self.H, t)
        p1 = self.ctrl1[0] + t[:, None] * (self.ctrl1[1] - self.ctrl1[0])
        p2 = self.ctrl2[0] + tp[:, None] * (self.ctrl2[1] - self.ctrl2[0])
        return p1, p2


class LineHomographyProblem:
    """RANSAC arm for H_e: data are line parameters t1, t2 of the K line correspondences."""

    sample_size = 3

    def __init__(self, t1: np.ndarray, t2: np.ndarray, len1: float, len2: float, threshold: float):
        # len1, len2: control-segment lengths in working-resolution px (t -> px along the line)
        self.t1, self.t2 = t1, t2
        self.len1, self.len2 = len1, len2
        self.threshold = threshold
        self.n = len(t1)
        self.pool = np.arange(self.n)

    def errors(self, H: np.ndarray) -> np.ndarray:
        """(M, 2, 2) -> (M, K) symmetric transfer error along the lines, working px."""
        fwd = np.abs(transfer(H, self.t1) - self.t2) * self.len2
        bwd = np.abs(transfer(inverse(H), self.t2) - self.t1) * self.len1
        e = 0.5 * (fwd + bwd)
        return np.where(np.isfinite(e), e, np.inf)

    def solve(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t1, t2 = self.t1[samples], self.t2[samples]
        ab1 = np.stack([1.0 - t1, t1], axis=-1)
        ab2 = np.stack([1.0 - t2, t2], axis=-1)
        H = line_homography_3pt(ab1, ab2)
        # a rank-deficient H_e maps the whole line to one point: not a line homography
        det = np.abs(np.linalg.det(H))
        ok = det > 1e-9
        return H[ok], np.flatnonzero(ok)

    def score(self, models: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return score_distances(self.errors(models), self.threshold, "msac")

    def local_optimize(self, model: np.ndarray) -> np.ndarray:
        inl = self.errors(model[None])[0] < self.threshold
        if np.count_nonzero(inl) < 4:
            return np.zeros((0, 2, 2))
        t1, t2 = self.t1[inl], self.t2[inl]
        H = line_homography_lsq(np.stack([1 - t1, t1], -1), np.stack([1 - t2, t2], -1))
        return H[None]


def fit_line_homography(
    pair: LinePair,
    pts1: np.ndarray,
    pts2: np.ndarray,
    image_size1: tuple[float, float],
    image_size2: tuple[float, float],
    scale1: float,
    scale2: float,
    rng: np.random.Generator,
    threshold: float = 0.5,
    confidence: float = 0.99,
    min_inliers: int = 4,
    max_samples: int = 200,
) -> tuple[LineHomographyFit | None, int]:
    """Stage 1 on one line pair: returns (fit or None, H_e hypotheses scored).

    The first control-point orientation is tried first, the swapped one only when it fails
    (fewer than ``min_inliers`` line correspondences agree with H_e), as in the paper.
    """
    support = pair.support
    ctrl1 = control_points(pair.line1, image_size1)
    base2 = control_points(pair.line2, image_size2)
    t1 = line_parameter(pts1[support], ctrl1)
    hyps = 0
    if len(support) < min_inliers:
        return None, 0
    for orientation, ctrl2 in ((1, base2), (2, base2[::-1].copy())):
        t2 = line_parameter(pts2[support], ctrl2)
        len1 = float(np.linalg.norm(ctrl1[1] - ctrl1[0])) * scale1
        len2 = float(np.linalg.norm(ctrl2[1] - ctrl2[0])) * scale2
        prob = LineHomographyProblem(t1, t2, len1, len2, threshold)
        res = run_ransac(
            [prob], rng, confidence=confidence, max_samples=max_samples, max_extra_lo=0
        )
        hyps += res.hypotheses
        if res.model is None:
            continue
        inl = prob.errors(res.model[None])[0] < threshold
        if np.count_nonzero(inl) >= min_inliers:
            return LineHomographyFit(
                pair, res.model, ctrl1, ctrl2, support[inl], hyps, orientation
            ), hyps
    return None, hyps


def line_homography_error(
    H: np.ndarray,
    control_points: tuple[np.ndarray, np.ndarray],
    pts1: np.ndarray,
    pts2: np.ndarray,
) -> np.ndarray:
    """Symmetric transfer error of H_e along the line pair, in pixels of the images (Fig. 8).

    The points are projected onto their lines (parameter t along the control points); the error
    is the mean of |t2 - H_e(t1)| * |c2' - c1'| and |t1 - H_e^-1(t2)| * |c2 - c1|.

    Args:
        H: (2, 2) H_e. control_points: ((2, 2), (2, 2)) of line 1 and line 2, px.
        pts1, pts2: (M, 2) matches on the line pair, px.
    Returns:
        (M,) errors in px (inf where a point maps to infinity).
    """
    c1, c2 = control_points
    prob = LineHomographyProblem(
        line_parameter(pts1, c1),
        line_parameter(pts2, c2),
        float(np.linalg.norm(c1[1] - c1[0])),
        float(np.linalg.norm(c2[1] - c2[0])),
        threshold=np.inf,
    )
    return prob.errors(np.asarray(H, dtype=np.float64)[None])[0]
