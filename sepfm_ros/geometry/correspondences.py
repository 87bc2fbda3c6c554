"""Matches prepared once per estimate: pixels, Hartley-normalised coordinates, design rows."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sepfm_ros.geometry.epipolar import apply_transform, normalization_transform
from sepfm_ros.geometry.solvers.design import epipolar_rows


@dataclass
class Correspondences:
    """pts1, pts2: (N, 2) pixels. x1, x2: (N, 2) normalised by T1, T2 (3, 3).
    rows: (N, 9) rows of x2^T F_n x1 = 0 in the normalised coordinates."""

    pts1: np.ndarray
    pts2: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    T1: np.ndarray
    T2: np.ndarray
    rows: np.ndarray

    @classmethod
    def from_pixels(cls, pts1: np.ndarray, pts2: np.ndarray) -> Correspondences:
        T1 = normalization_transform(pts1)
        T2 = normalization_transform(pts2)
        x1, x2 = apply_transform(T1, pts1), apply_transform(T2, pts2)
        return cls(pts1, pts2, x1, x2, T1, T2, epipolar_rows(x1, x2))

    def __len__(self) -> int:
        return int(self.pts1.shape[0])
