"""Stage 2's arm: the fundamental-matrix problem with the line pair's fixed correspondences in
every sample (paper Sec. 5, step two: 3 fixed + 4 sampled, seven-point; or + 5, eight-point),
and the optional in-sample plane check of :mod:`~sepfm_ros.geometry.separable.line_planes`."""

from __future__ import annotations

from typing import Any

import numpy as np

from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.separable.line_planes import line_plane_basis, plane_free_samples

__all__ = ["Stage2Problem"]


class Stage2Problem(FundamentalProblem):
    """A :class:`FundamentalProblem` with fixed line correspondences and, when ``plane_tol`` is
    positive, the in-sample plane check: a sample two of whose points share a plane with the
    line (both points' transfer errors under their least-squares homography with the line below
    ``plane_tol`` px, :func:`~sepfm_ros.geometry.separable.line_planes.line_plane_degenerate`)
    is rejected before it is solved; it still counts as drawn. Other arguments: those of
    :class:`FundamentalProblem`."""

    def __init__(self, *args: Any, plane_tol: float = 0.0, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.plane_basis = np.zeros((9, 0))
        self.plane_tol = 0.0
        if plane_tol > 0 and len(self.f1) >= 3:
            self.plane_basis = line_plane_basis(self.f1, self.f2)
            # px -> image 2 normalised
            self.plane_tol = float(plane_tol) * float(self.data.T2[0, 0])

    @property
    def plain_solve(self) -> bool:
        """False when the in-sample plane check is on (it leaves samples out before solving)."""
        return self.plane_basis.shape[1] != 4

    def solve(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B, k) indices -> (F (K, 3, 3) in pixels, index into ``samples`` (K,)), the
        plane-degenerate samples left out when the check is on."""
        if self.plane_basis.shape[1] != 4:
            return super().solve(samples)
        keep = plane_free_samples(
            self.plane_basis, self.data.x1, self.data.x2, samples, self.plane_tol
        )
        models, sid = super().solve(np.ascontiguousarray(samples[keep]))
        return models, keep[sid]
