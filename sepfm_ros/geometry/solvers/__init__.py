"""Minimal and least-squares solvers, one file each. All batched over a leading axis M.

- :func:`seven_point`: F from 7 correspondences (up to 3 real roots per sample).
- :func:`eight_point`: F from >= 8 correspondences (linear least squares + rank 2).
- :func:`line_homography_3pt`: the paper's 2x2 epipolar line homography H_e from 3 line points.
- ``cholesky``: small SPD factorisations and solves shared by the LM step and the refits.
"""

from sepfm_ros.geometry.solvers.eight_point import eight_point
from sepfm_ros.geometry.solvers.line_homography import line_homography_3pt, line_homography_lsq
from sepfm_ros.geometry.solvers.seven_point import seven_point

__all__ = ["eight_point", "line_homography_3pt", "line_homography_lsq", "seven_point"]
