"""Seven-point algorithm, batched: each real root of the cubic det(F) = 0 is one model."""

from __future__ import annotations

import numpy as np

from sepfm_ros.geometry.solvers.design import epipolar_rows

# det(F2 + s (F1 - F2)) is a cubic in s; sample it at these s and solve for the coefficients.
_S = np.array([0.0, 1.0, -1.0, 2.0])
_VANDER_INV = np.linalg.inv(np.vander(_S, 4))  # rows: s^3, s^2, s, 1


def seven_point(x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All real-root F of M seven-point samples.

    With K > 7 correspondences per sample the two-dimensional null space is the least-squares
    one (the two smallest right singular vectors), which is exact when the rows have rank 7,
    e.g. 4 general points plus any number of points on one 3D line (they give 3 constraints).

    Args:
        x1, x2: (M, K, 2) correspondences, K >= 7 (normalised coordinates recommended).
    Returns:
        (F, sample): F (K, 3, 3) unit-norm models, K <= 3M; sample (K,) int index of the sample
        each model came from.
    """
    if x1.ndim != 3 or x1.shape[1] < 7:
        raise ValueError(f"seven_point expects (M, K >= 7, 2) inputs, got {x1.shape}")
    M, K = x1.shape[:2]
    A = epipolar_rows(x1, x2)  # (M, K, 9)
    if K < 9:
        A = np.concatenate([A, np.zeros((M, 9 - K, 9))], axis=1)  # square up for a full SVD
    _, _, Vt = np.linalg.svd(A)
    F1 = Vt[:, -1].reshape(M, 3, 3)
    F2 = Vt[:, -2].reshape(M, 3, 3)
    D = F1 - F2
    dets = np.linalg.det(F2[:, None] + _S[None, :, None, None] * D[:, None])  # (M, 4)
    coeffs = dets @ _VANDER_INV.T  # (M, 4): c3, c2, c1, c0
    c3 = coeffs[:, 0]
    scale = np.max(np.abs(coeffs), axis=1)
    scale = np.where(scale == 0, 1.0, scale)
    # A vanishing leading coefficient means one root at infinity (F = D); keep it finite.
    tiny = np.abs(c3) < 1e-12 * scale
    c3 = np.where(tiny, np.where(c3 >= 0, 1e-12, -1e-12) * scale, c3)
    comp = np.zeros((M, 3, 3))
    comp[:, 0, :] = -coeffs[:, 1:] / c3[:, None]
    comp[:, 1, 0] = 1.0
    comp[:, 2, 1] = 1.0
    roots = np.linalg.eigvals(comp)  # (M, 3)
    real = np.abs(roots.imag) <= 1e-8 * (1.0 + np.abs(roots.real))
    sample, which = np.nonzero(real)
    s = roots.real[sample, which]
    F = F2[sample] + s[:, None, None] * D[sample]
    norms = np.linalg.norm(F.reshape(-1, 9), axis=1)
    good = np.isfinite(norms) & (norms > 0)
    F = F[good] / norms[good, None, None]
    return F, sample[good]
