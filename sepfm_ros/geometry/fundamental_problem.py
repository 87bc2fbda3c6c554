"""The fundamental-matrix RANSAC problem: seven- or eight-point samples, optionally with fixed
correspondences (the separable method's stage 2), symmetric-epipolar scoring, and LO refits.

Every method of :func:`sepfm_ros.geometry.estimate_fundamental` (ours and the baselines) samples,
solves, scores and refines through this one class, so their comparison is fair.
"""

from __future__ import annotations

import numba
import numpy as np

from sepfm_ros.geometry.correspondences import Correspondences
from sepfm_ros.geometry.epipolar import apply_transform, denormalize_kernel, msac_kernel
from sepfm_ros.geometry.refine import iterative_refit
from sepfm_ros.geometry.solvers.eight_point import eight_point_kernel
from sepfm_ros.geometry.solvers.seven_point import seven_point_kernel

SCORINGS = ("msac", "lmeds")


@numba.njit(cache=True, nogil=True, inline="always")
def _basis(p: np.ndarray, q: np.ndarray, r: np.ndarray, s: np.ndarray, M: np.ndarray) -> None:
    """M (3, 3) with M e_1 ~ p, M e_2 ~ q, M e_3 ~ r and M (1, 1, 1) ~ s (homogeneous (3,))."""
    # lambda = adj([p q r]) s: the columns' weights up to the determinant's scale
    l0 = (q[1] * r[2] - q[2] * r[1]) * s[0] + (q[2] * r[0] - q[0] * r[2]) * s[1]
    l0 += (q[0] * r[1] - q[1] * r[0]) * s[2]
    l1 = (r[1] * p[2] - r[2] * p[1]) * s[0] + (r[2] * p[0] - r[0] * p[2]) * s[1]
    l1 += (r[0] * p[1] - r[1] * p[0]) * s[2]
    l2 = (p[1] * q[2] - p[2] * q[1]) * s[0] + (p[2] * q[0] - p[0] * q[2]) * s[1]
    l2 += (p[0] * q[1] - p[1] * q[0]) * s[2]
    for i in range(3):
        M[i, 0], M[i, 1], M[i, 2] = l0 * p[i], l1 * q[i], l2 * r[i]


@numba.njit(cache=True, nogil=True)
def line_plane_error(c1, c2, u1, u2, v1, v2) -> float:
    """How far two matches (u1 -> u2, v1 -> v2) are from sharing a plane with a 3D line.

    c1, c2: (3, 2) three correspondences on the line (ends first and last); u*, v*: (2,) points.
    The homography through the line's two end points and the two matches (4 points, exact) maps
    the middle line point of image 1 to its match when, and only when (for correct matches in
    general position), the 5 points are images of one 3D plane: 3 collinear correspondences fix
    5 of a plane homography's 8 degrees of freedom and 2 more points fix 4, so 1 is left over.
    Returns the distance (units of image 2's coordinates) between the transferred and the
    matched middle point, inf when the 4 points are degenerate.
    """
    P1 = np.empty((4, 3))
    P2 = np.empty((4, 3))
    for c in range(2):
        P1[0, c], P1[1, c], P1[2, c], P1[3, c] = c1[0, c], c1[2, c], u1[c], v1[c]
        P2[0, c], P2[1, c], P2[2, c], P2[3, c] = c2[0, c], c2[2, c], u2[c], v2[c]
    for i in range(4):
        P1[i, 2] = 1.0
        P2[i, 2] = 1.0
    M1 = np.empty((3, 3))
    M2 = np.empty((3, 3))
    _basis(P1[0], P1[1], P1[2], P1[3], M1)
    _basis(P2[0], P2[1], P2[2], P2[3], M2)
    # H = M2 adj(M1); transfer the middle point: h = M2 (adj(M1) b)
    b = np.array([c1[1, 0], c1[1, 1], 1.0])
    a = np.empty(3)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        # row i of adj(M1) is the cross product of columns j and k of M1
        a[i] = (
            (M1[1, j] * M1[2, k] - M1[2, j] * M1[1, k]) * b[0]
            + (M1[2, j] * M1[0, k] - M1[0, j] * M1[2, k]) * b[1]
            + (M1[0, j] * M1[1, k] - M1[1, j] * M1[0, k]) * b[2]
        )
    h0 = M2[0, 0] * a[0] + M2[0, 1] * a[1] + M2[0, 2] * a[2]
    h1 = M2[1, 0] * a[0] + M2[1, 1] * a[1] + M2[1, 2] * a[2]
    h2 = M2[2, 0] * a[0] + M2[2, 1] * a[1] + M2[2, 2] * a[2]
    scale = abs(h0) + abs(h1) + abs(h2)
    if not scale > 0 or abs(h2) <= 1e-12 * scale:
        return np.inf
    e = np.hypot(h0 / h2 - c2[1, 0], h1 / h2 - c2[1, 1])
    return e if np.isfinite(e) else np.inf


@numba.njit(cache=True, nogil=True)
def line_plane_degenerate(c1, c2, x1, x2, sample, tol) -> bool:
    """True when some two points of ``sample`` lie on one plane with the line (see
    :func:`line_plane_error`; transfer error below ``tol``)."""
    k = sample.shape[0]
    for i in range(k):
        for j in range(i + 1, k):
            p, q = sample[i], sample[j]
            if line_plane_error(c1, c2, x1[p], x2[p], x1[q], x2[q]) < tol:
                return True
    return False


@numba.njit(cache=True, nogil=True)
def solve_samples_kernel(f1, f2, x1, x2, samples, T1, T2, seven, c1, c2, plane_tol):
    """Minimal (or fixed + sampled) solves of B samples, in one compiled call.

    f1, f2: (f, 2) fixed normalised correspondences put in front of every sample; x1, x2: (N, 2)
    normalised coordinates; samples: (B, k) indices; T1, T2: (3, 3) normalising transforms.
    seven: seven-point (each real root a model) or eight-point. c1, c2: (3, 2) normalised line
    points (ends first and last) of the in-sample plane check, or (0, 2) for none; a sample in
    which two points share a plane with the line (``line_plane_degenerate`` at ``plane_tol``,
    image 2's normalised units) yields no model. Returns (F (K, 3, 3) in px at unit Frobenius
    norm, (K,) sample index of each model).
    """
    B, k, f = samples.shape[0], samples.shape[1], f1.shape[0]
    keep = np.empty(B, dtype=np.int64)
    n_keep = 0
    for b in range(B):
        if c1.shape[0] == 3 and line_plane_degenerate(c1, c2, x1, x2, samples[b], plane_tol):
            continue
        keep[n_keep] = b
        n_keep += 1
    if n_keep == 0:
        return np.empty((0, 3, 3)), np.empty(0, dtype=np.int64)
    y1 = np.empty((n_keep, f + k, 2))
    y2 = np.empty((n_keep, f + k, 2))
    for i in range(n_keep):
        b = keep[i]
        for j in range(f + k):
            for c in range(2):
                y1[i, j, c] = f1[j, c] if j < f else x1[samples[b, j - f], c]
                y2[i, j, c] = f2[j, c] if j < f else x2[samples[b, j - f], c]
    if seven:
        F_n, sid = seven_point_kernel(y1, y2)
    else:
        F_n = eight_point_kernel(y1, y2, np.ones((n_keep, f + k)))
        sid = np.arange(n_keep)
    F = np.empty_like(F_n)
    out_sid = np.empty_like(sid)
    n_out = 0
    for m in range(F_n.shape[0]):
        if denormalize_kernel(F_n[m], T1, T2, F[n_out]):
            out_sid[n_out] = keep[sid[m]]
            n_out += 1
    return F[:n_out], out_sid[:n_out]


def line_check_points(f1: np.ndarray, f2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, 2), (3, 2): the two extreme and the median of (f, 2) collinear correspondences along
    their principal direction in image 1 (ends first and last), for the in-sample plane check."""
    d = f1 - f1.mean(axis=0)
    _, _, Vt = np.linalg.svd(d, full_matrices=False)
    order = np.argsort(d @ Vt[0])
    pick = order[[0, len(order) // 2, -1]]
    return np.ascontiguousarray(f1[pick]), np.ascontiguousarray(f2[pick])


#: Inlier-threshold factors of the local optimisation inside RANSAC (plain least squares; the
#: Sampson refinement is left to the final model).
LO_FACTORS = (2.0, 1.0)


def score_distances(d: np.ndarray, threshold: float, scoring: str) -> tuple[np.ndarray, np.ndarray]:
    """(K, N) distances in px -> (cost (K,), inlier count (K,)).

    msac: sum of min(d^2, t^2) (truncated quadratic); lmeds: median of d^2.
    """
    count = np.count_nonzero(d < threshold, axis=1)
    if scoring == "lmeds":
        cost = np.median(d * d, axis=1)
    else:
        cost = np.minimum(d * d, threshold * threshold).sum(axis=1)
    return cost, count


class FundamentalProblem:
    """One RANSAC arm estimating F.

    Args:
        data: the correspondences.
        solver: "seven" (seven-point, k = 7 - f) or "eight" (eight-point, k = 8 - f).
        threshold: inlier threshold in px of symmetric epipolar distance.
        scoring: "msac" or "lmeds".
        fixed1, fixed2: (f, 2) pixel correspondences kept in every sample: none, the paper's 3
            line correspondences, or all line correspondences (f >= 3) as a least-squares block
            that fixes the same 3 degrees of freedom with the noise averaged.
        pool: indices of ``data`` eligible for sampling (default: all).
        plane_tol: in-sample plane check (0: off): with at least 3 fixed line correspondences,
            a sample two of whose points share a plane with the line (the middle line point's
            transfer error under their homography below ``plane_tol`` px, see
            :func:`line_plane_error`) is rejected before it is solved; it still counts as drawn.
    """

    def __init__(
        self,
        data: Correspondences,
        solver: str = "seven",
        threshold: float = 1.0,
        scoring: str = "msac",
        fixed1: np.ndarray | None = None,
        fixed2: np.ndarray | None = None,
        pool: np.ndarray | None = None,
        plane_tol: float = 0.0,
    ) -> None:
        if solver not in ("seven", "eight"):
            raise ValueError(f"unknown solver {solver!r}")
        if scoring not in SCORINGS:
            raise ValueError(f"unknown scoring {scoring!r}; expected one of {SCORINGS}")
        self.data = data
        self.solver = solver
        self.threshold = float(threshold)
        self.scoring = scoring
        f = 0 if fixed1 is None else min(3, len(fixed1))  # DOF fixed by line points
        self.f1 = np.zeros((0, 2)) if fixed1 is None else apply_transform(data.T1, fixed1)
        self.f2 = np.zeros((0, 2)) if fixed2 is None else apply_transform(data.T2, fixed2)
        self.f1, self.f2 = np.ascontiguousarray(self.f1), np.ascontiguousarray(self.f2)
        self.sample_size = (7 if solver == "seven" else 8) - f
        self.pool = np.arange(len(data)) if pool is None else np.asarray(pool, dtype=np.int64)
        self.n = len(data)
        self.c1 = self.c2 = np.zeros((0, 2))
        self.plane_tol = 0.0
        if plane_tol > 0 and len(self.f1) >= 3:
            self.c1, self.c2 = line_check_points(self.f1, self.f2)
            self.plane_tol = float(plane_tol) * float(data.T2[0, 0])  # px -> image 2 normalised

    def solve(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B, k) indices -> (F (K, 3, 3) in pixels, sample index (K,))."""
        return solve_samples_kernel(
            self.f1, self.f2, self.data.x1, self.data.x2, samples, self.data.T1, self.data.T2,
            self.solver == "seven", self.c1, self.c2, self.plane_tol,
        )  # fmt: skip

    def distances(self, F: np.ndarray) -> np.ndarray:
        """(K, 3, 3) -> (K, N) symmetric epipolar distances in px."""
        return self.data.distances(F)

    def score(self, models: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.scoring == "msac":  # compiled, no (K, N) distance matrix
            return msac_kernel(models, self.data.X1, self.data.X2, self.threshold)
        return score_distances(self.distances(models), self.threshold, self.scoring)

    def local_optimize(self, model: np.ndarray) -> np.ndarray:
        """Iterative least-squares refits of ``model`` on its inliers (see iterative_refit)."""
        return iterative_refit(
            model, self.data, self.threshold, factors=LO_FACTORS, irls_iterations=0
        )
