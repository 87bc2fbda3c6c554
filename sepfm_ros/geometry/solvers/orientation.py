"""The oriented epipolar constraint (Chum, Werner & Matas 2004) on a minimal sample's models.

A scene point in front of both cameras projects to x1, x2 (homogeneous, last coordinate
positive) with e2 x x2 ~+ F x1: the line through the epipole e2 (F^T e2 = 0) and x2 points the
same way as the epipolar line of x1, for every match of the scene alike. A model for which the
sample's own matches disagree in this sign cannot have all of them in front of both cameras, so
at least one is an outlier for it: it is rejected before it is scored. It is most often a
spurious root of the seven-point cubic. The test is invariant to the signs of F and e2 and to
the normalising transforms (positive scale, last coordinate kept).
"""

from __future__ import annotations

import numba
import numpy as np

#: Products |(e2 x x2) . (F x1)| below this fraction of the sample's largest decide no sign (a
#: point at the epipole, where the sign is noise).
SIGN_FLOOR = 1e-9


@numba.njit(cache=True, nogil=True)
def left_epipole(F: np.ndarray, e: np.ndarray) -> bool:
    """e (3,) = the epipole in image 2 (F^T e = 0) of F (3, 3) or (9,) row-major: the largest of
    the cross products of F's column pairs; False when F has rank < 2 (every product 0)."""
    f = F.reshape(9)
    best = 0.0
    for a, b in ((0, 1), (0, 2), (1, 2)):
        c0 = f[3 + a] * f[6 + b] - f[6 + a] * f[3 + b]
        c1 = f[6 + a] * f[b] - f[a] * f[6 + b]
        c2 = f[a] * f[3 + b] - f[3 + a] * f[b]
        n = c0 * c0 + c1 * c1 + c2 * c2
        if n > best:
            best = n
            e[0], e[1], e[2] = c0, c1, c2
    return best > 0.0


@numba.njit(cache=True, nogil=True)
def oriented_consistent(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> bool:
    """True when the K matches (K, 2) x1 <-> x2 (inhomogeneous, any common affine normalisation)
    all give (e2 x x2) . (F x1) one sign under F (3, 3) or (9,) row-major (products at the
    epipole, below ``SIGN_FLOOR`` of the largest, are skipped); True when F has no epipole."""
    f = F.reshape(9)
    e = np.empty(3)
    if not left_epipole(F, e):
        return True
    K = x1.shape[0]
    s = np.empty(K)
    big = 0.0
    for k in range(K):
        x, y, u, v = x1[k, 0], x1[k, 1], x2[k, 0], x2[k, 1]
        l0 = f[0] * x + f[1] * y + f[2]  # F x1
        l1 = f[3] * x + f[4] * y + f[5]
        l2 = f[6] * x + f[7] * y + f[8]
        m0 = e[1] - e[2] * v  # e2 x (u, v, 1)
        m1 = e[2] * u - e[0]
        m2 = e[0] * v - e[1] * u
        s[k] = m0 * l0 + m1 * l1 + m2 * l2
        big = max(big, abs(s[k]))
    floor = SIGN_FLOOR * big
    sign = 0.0
    for k in range(K):
        if abs(s[k]) <= floor:
            continue
        if sign == 0.0:
            sign = s[k]
        elif sign * s[k] < 0.0:
            return False
    return True
