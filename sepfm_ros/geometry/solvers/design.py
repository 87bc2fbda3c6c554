"""The epipolar design matrix shared by the seven- and eight-point solvers."""

from __future__ import annotations

import numpy as np


def epipolar_rows(x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Rows of the linear system x2^T F x1 = 0 in the unknowns vec(F) (row-major).

    Args:
        x1, x2: (..., K, 2) inhomogeneous (normalised) coordinates.
    Returns:
        (..., K, 9) with row = kron([x2, 1], [x1, 1]).
    """
    ones = np.ones(x1.shape[:-1] + (1,))
    h1 = np.concatenate([x1, ones], axis=-1)
    h2 = np.concatenate([x2, ones], axis=-1)
    return (h2[..., :, None] * h1[..., None, :]).reshape(*x1.shape[:-1], 9)
