"""Stage 1 of the separable method: RANSAC for the epipolar line homography H_e on a line pair.

Points on the line pair are written in control-point coordinates (parameter t along the segment
between the two control points, i.e. (alpha, beta) = (1 - t, t)); H_e is found by sampling 3
correspondences (minimal solver) with threshold T1 (px at the working resolution) on the
symmetric transfer error along the lines, and adaptive termination F(3, r). The whole RANSAC loop
(sampling, minimal solve, scoring, local optimisation, stopping) is one compiled kernel,
:func:`stage1_ransac`, fed uniform numbers drawn from the caller's generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from sepfm_ros.geometry.robust.trials import trials_needed
from sepfm_ros.geometry.separable.line_pairs import LinePair, control_points, line_parameter
from sepfm_ros.geometry.solvers.line_homography import (
    line_homography_3pt_kernel,
    line_homography_lsq_kernel,
    transfer,
    transfer_kernel,
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


@numba.njit(cache=True, nogil=True)
def transfer_errors(
    h: np.ndarray, t1: np.ndarray, t2: np.ndarray, len1: float, len2: float, out: np.ndarray
) -> None:
    """Symmetric transfer error along the lines of H_e h (4,) into out (K,), working px.

    Mean of |H_e(t1) - t2| * len2 and |H_e^-1(t2) - t1| * len1 (inf where a point maps to
    infinity); len1, len2 convert t to px (control-segment lengths).
    """
    a, b, c, d = h[0], h[1], h[2], h[3]
    for i in range(len(t1)):
        fwd = abs(transfer_kernel(a, b, c, d, t1[i]) - t2[i]) * len2
        bwd = abs(transfer_kernel(d, -b, -c, a, t2[i]) - t1[i]) * len1
        e = 0.5 * (fwd + bwd)
        out[i] = e if np.isfinite(e) else np.inf


@numba.njit(cache=True, nogil=True)
def _msac(err: np.ndarray, threshold: float) -> tuple[float, int]:
    """Truncated quadratic cost sum(min(e^2, T^2)) and inlier count (e < T) of (K,) errors."""
    t2 = threshold * threshold
    cost = 0.0
    count = 0
    for e in err:
        cost += min(e * e, t2)
        if e < threshold:
            count += 1
    return cost, count


@numba.njit(cache=True, nogil=True)
def stage1_ransac(
    t1: np.ndarray,
    t2: np.ndarray,
    len1: float,
    len2: float,
    threshold: float,
    confidence: float,
    uniforms: np.ndarray,
    batch: int = 64,
) -> tuple[np.ndarray, bool, int]:
    """RANSAC for H_e on K line correspondences, compiled: (h (4,), found, hypotheses).

    The loop of :func:`sepfm_ros.geometry.robust.loop.run_ransac` for one arm: samples of 3 in
    batches growing 1, 1, 2, 4, ... (at most ``batch``), minimal solve, MSAC score at
    ``threshold``, local optimisation (least squares on the inliers, at least 4) of every
    minimal-sample model that beats the best minimal-sample model so far, adaptive stopping
    after F(3, r) samples (:func:`~sepfm_ros.geometry.robust.trials.trials_needed`, shared with the
    generic loop). It stays a compiled twin because stage 1 runs once per line pair on a few
    dozen points, where the generic loop's per-batch Python overhead would dominate; a parity
    test (test_line_pairs_stage1.py) runs both loops on the same data.

    Args:
        t1, t2: (K,) line parameters of the correspondences (K >= 3).
        len1, len2: control-segment lengths, working px (t -> px along the lines).
        threshold: T1, working px. confidence: p of F(3, r).
        uniforms: (S, 3) uniform [0, 1) numbers from the caller's generator; S = max samples.
            Row s picks sample s (3 distinct correspondences).
    """
    K = len(t1)
    cap = uniforms.shape[0]
    best = np.zeros(4)
    best_cost = np.inf
    best_count = -1
    best_raw_cost = np.inf
    hyps = 0
    samples = 0
    h = np.empty(4)
    s1 = np.empty(3)
    s2 = np.empty(3)
    err = np.empty(K)
    bh = np.empty(4)
    if K < 3 or cap == 0:
        return best, False, 0
    while True:
        need = max(trials_needed(3, max(best_count, 0), K, confidence, cap), 1)
        b = min(max(need - samples, 1), min(batch, max(1, samples)))
        b = min(b, cap - samples)
        if b > 0:
            b_cost = np.inf
            b_count = 0
            for s in range(samples, samples + b):
                u = uniforms[s]
                i0 = min(int(u[0] * K), K - 1)
                i1 = min(int(u[1] * (K - 1)), K - 2)
                if i1 >= i0:
                    i1 += 1
                i2 = min(int(u[2] * (K - 2)), K - 3)
                lo, hi = min(i0, i1), max(i0, i1)
                if i2 >= lo:
                    i2 += 1
                if i2 >= hi:
                    i2 += 1
                s1[0], s1[1], s1[2] = t1[i0], t1[i1], t1[i2]
                s2[0], s2[1], s2[2] = t2[i0], t2[i1], t2[i2]
                line_homography_3pt_kernel(s1, s2, h)
                # a rank-deficient H_e maps the whole line to one point: not a line homography
                if not abs(h[0] * h[3] - h[1] * h[2]) > 1e-9:
                    continue
                transfer_errors(h, t1, t2, len1, len2, err)
                cost, count = _msac(err, threshold)
                hyps += 1
                if cost < b_cost:
                    b_cost = cost
                    b_count = count
                    bh[:] = h
            samples += b
            if b_cost < best_cost:
                best[:] = bh
                best_cost, best_count = b_cost, b_count
            if b_cost < best_raw_cost:
                best_raw_cost = b_cost
                # local optimisation: least squares on the inliers of the batch's best model
                transfer_errors(bh, t1, t2, len1, len2, err)
                inl = err < threshold
                if np.count_nonzero(inl) >= 4:
                    lh = line_homography_lsq_kernel(t1, t2, inl)
                    transfer_errors(lh, t1, t2, len1, len2, err)
                    cost, count = _msac(err, threshold)
                    hyps += 1
                    if cost < best_cost:
                        best[:] = lh
                        best_cost, best_count = cost, count
        if best_count >= 0 and samples >= trials_needed(3, best_count, K, confidence, cap):
            break
        if samples >= cap:
            break
    return best, best_count >= 0, hyps


def _as_matrix(h: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(h, dtype=np.float64).reshape(2, 2).copy()


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
    len1 = math.hypot(*(ctrl1[1] - ctrl1[0])) * scale1
    err = np.empty(len(support))
    for orientation, ctrl2 in ((1, base2), (2, base2[::-1].copy())):
        t2 = line_parameter(pts2[support], ctrl2)
        len2 = math.hypot(*(ctrl2[1] - ctrl2[0])) * scale2
        uniforms = rng.random((max_samples, 3))
        h, found, n_hyp = stage1_ransac(
            t1, t2, len1, len2, float(threshold), float(confidence), uniforms
        )
        hyps += int(n_hyp)
        if not found:
            continue
        transfer_errors(h, t1, t2, len1, len2, err)
        inl = err < threshold
        if np.count_nonzero(inl) >= min_inliers:
            return LineHomographyFit(
                pair, _as_matrix(h), ctrl1, ctrl2, support[inl], hyps, orientation
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
    t1 = np.ascontiguousarray(line_parameter(pts1, c1), dtype=np.float64)
    t2 = np.ascontiguousarray(line_parameter(pts2, c2), dtype=np.float64)
    out = np.empty(len(t1))
    h = np.ascontiguousarray(H, dtype=np.float64).reshape(4)
    len1 = float(np.linalg.norm(c1[1] - c1[0]))
    len2 = float(np.linalg.norm(c2[1] - c2[0]))
    transfer_errors(h, t1, t2, len1, len2, out)
    return out
