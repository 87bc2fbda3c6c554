"""Ahead-of-use compilation of the estimator's numba kernels.

The kernels compile on first use (seconds to tens of seconds on a fresh install) and are cached
on disk beside their modules, so later processes only load them (well under a second). A
long-running process calls :func:`warm_up` once at start so its first frame is not the one that
pays; tests call it once per session so node subprocesses find a warm cache.
"""

from __future__ import annotations

import time

import numpy as np

from sepfm_ros.geometry.estimator import METHODS, estimate_fundamental
from sepfm_ros.geometry.fundamental.shifted_plane import (
    cell_grid,
    count_near,
    nearest_within,
    period_hits,
)
from sepfm_ros.geometry.synthetic import make_pair


def warm_up() -> float:
    """Run every method once on two small synthetic pairs (compiling or loading each kernel):
    one with most matches inliers (75 %) and one with half (50 %), under the inlier ratio up
    to which the local optimisation samples inside the inliers
    (:data:`~sepfm_ros.geometry.fundamental.inner_sampling.MAX_INLIER_RATIO`), so its kernels
    are not left to compile on the first such pair of a stream.

    Returns:
        Seconds spent.
    """
    t0 = time.perf_counter()
    for outliers in (20, 60):
        pair = make_pair(
            n_inliers=60, n_outliers=outliers, n_lines=2, points_per_line=10, noise=0.3, seed=0
        )
        for method in METHODS:
            estimate_fundamental(pair.pts1, pair.pts2, pair.image_size, method=method, seed=0)
    # the shifted-plane check's kernels run only on a planar scene, which the pair is not
    plane = np.ascontiguousarray(pair.pts2)
    nearest_within(plane, plane[:4], 1.0)
    grid = cell_grid(plane, 1.0)
    _, radius = period_hits(plane, np.eye(3), np.eye(3), grid, 1.0, 0.15)
    count_near(plane, grid, plane[: len(radius)], radius, 1.0)
    return time.perf_counter() - t0
