"""Least median of squares (Rousseeuw & Leroy 1987; Zhang 1998 for F): the robust scale of a
model's residuals, shared by the arms of one estimate, and its robust inliers."""

from __future__ import annotations

import numpy as np

__all__ = [
    "LMEDS_INLIER",
    "LMEDS_MIN_SCALE",
    "LMEDS_SCALE",
    "RobustScale",
    "lmeds_final_inliers",
    "lmeds_inliers",
    "robust_scale",
]

#: Robust scale of least median of squares (Rousseeuw & Leroy 1987; Zhang 1998 for F):
#: sigma = LMEDS_SCALE * (1 + 5 / (n - p)) * sqrt(median d^2), inliers d < LMEDS_INLIER * sigma.
LMEDS_SCALE = 1.4826
LMEDS_INLIER = 2.5
#: Least robust scale, px: on noise-free data the residuals are rounding errors (~1e-13 px) and
#: a scale from them would call half of the exact matches outliers.
LMEDS_MIN_SCALE = 1e-6


def robust_scale(median_sq: np.ndarray | float, n: int, p: int) -> np.ndarray | float:
    """LMedS robust scale (px) from the median of squared residuals over n matches, sample size p.

    sigma = 1.4826 * (1 + 5 / (n - p)) * sqrt(median d^2): 1.4826 makes it consistent for
    Gaussian residuals, (1 + 5 / (n - p)) corrects the small-sample bias; at least
    LMEDS_MIN_SCALE.
    """
    return np.maximum(
        LMEDS_SCALE * (1.0 + 5.0 / max(n - p, 1)) * np.sqrt(median_sq), LMEDS_MIN_SCALE
    )


class RobustScale:
    """The robust scale (px) of the best LMedS model so far, shared by every arm of one estimate,
    so inlier counts of different models and arms are comparable (the race compares them).

    ``sigma`` only shrinks: the best model has the lowest median and so the lowest scale.
    """

    def __init__(self) -> None:
        self.sigma = np.inf

    def update(self, sigma: float) -> None:
        self.sigma = min(self.sigma, float(sigma))

    @property
    def threshold(self) -> float:
        """Robust inlier threshold (px): LMEDS_INLIER * sigma."""
        return LMEDS_INLIER * self.sigma


def lmeds_inliers(d: np.ndarray, p: int) -> tuple[np.ndarray, float, float]:
    """(N,) residuals (px) of one model -> (robust inlier mask, robust scale px, median d^2)."""
    med = float(np.median(d * d))
    sigma = float(robust_scale(med, d.shape[0], p))
    return d < LMEDS_INLIER * sigma, sigma, med


def lmeds_final_inliers(d: np.ndarray, p: int) -> tuple[np.ndarray, float, float]:
    """Final LMedS inliers of one model from its (N,) residuals (px), Rousseeuw & Leroy's
    reweighted scale: the preliminary scale s0 (:func:`robust_scale`) marks w_i = [d_i < 2.5
    s0]; sigma = sqrt(sum w_i d_i^2 / (sum w_i - p)) (no longer inflated by the outliers above
    the median); inliers d < 2.5 sigma. Returns (inlier mask, sigma px, median d^2)."""
    first, _, med = lmeds_inliers(d, p)
    k = int(np.count_nonzero(first))
    if k <= p:
        return first, float(robust_scale(med, d.shape[0], p)), med
    sigma = max(float(np.sqrt(np.sum(d[first] ** 2) / (k - p))), LMEDS_MIN_SCALE)
    return d < LMEDS_INLIER * sigma, sigma, med
