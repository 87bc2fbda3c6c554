"""Matches prepared once per estimate: pixels, Hartley-normalised coordinates, homogeneous rows."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sepfm_ros.geometry.epipolar import (
    hartley_kernel,
    homogeneous_columns,
    reading_copy,
    symmetric_epipolar_distance_h,
)


@dataclass
class Correspondences:
    """pts1, pts2: (N, 2) pixels. x1, x2: (N, 2) normalised by T1, T2 (3, 3).
    X1, X2: (3, N) homogeneous pixel coordinates (for scoring)."""

    pts1: np.ndarray
    pts2: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    T1: np.ndarray
    T2: np.ndarray
    X1: np.ndarray
    X2: np.ndarray
    #: (order, its :func:`~sepfm_ros.geometry.epipolar.reading_copy`) of :meth:`in_order`
    _in_order: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False, compare=False)

    @classmethod
    def from_pixels(cls, pts1: np.ndarray, pts2: np.ndarray) -> Correspondences:
        pts1 = np.ascontiguousarray(pts1, dtype=np.float64)
        pts2 = np.ascontiguousarray(pts2, dtype=np.float64)
        T1, x1 = hartley_kernel(pts1)
        T2, x2 = hartley_kernel(pts2)
        X1 = homogeneous_columns(pts1)
        X2 = homogeneous_columns(pts2)
        return cls(pts1, pts2, x1, x2, T1, T2, X1, X2)

    def spread(self, k: int) -> Correspondences:
        """At most ``k`` >= 1 of the matches, taken evenly along their order (match i * N // k
        for i < k: with the matches sorted best first, every quality in proportion), in the
        same normalised coordinates (T1, T2); ``self`` when N <= k."""
        n = len(self)
        if n <= k:
            return self
        idx = np.arange(k, dtype=np.int64) * n // k
        return Correspondences(
            self.pts1[idx], self.pts2[idx], self.x1[idx], self.x2[idx], self.T1, self.T2,
            np.ascontiguousarray(self.X1[:, idx]), np.ascontiguousarray(self.X2[:, idx]),
        )  # fmt: skip

    def in_order(self, order: np.ndarray) -> np.ndarray:
        """(4, N) the pixel points (x1, y1, x2, y2 rows) read in ``order`` (N,), the SPRT's
        reading order; made once for the last order asked (every arm of an estimate reads the
        same)."""
        cached = self._in_order
        if cached is None or cached[0] is not order:
            cached = self._in_order = (order, reading_copy(self.X1, self.X2, order))
        return cached[1]

    def distances(self, F: np.ndarray) -> np.ndarray:
        """Symmetric epipolar distances (px) of (3, 3) -> (N,) or (M, 3, 3) -> (M, N) models."""
        if F.ndim == 2:
            return symmetric_epipolar_distance_h(F[None], self.X1, self.X2)[0]
        return symmetric_epipolar_distance_h(F, self.X1, self.X2)

    def __len__(self) -> int:
        return int(self.pts1.shape[0])
