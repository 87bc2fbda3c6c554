"""Ahead-of-use compilation of the pipeline's numba kernels (matching) and the estimator's.

See :mod:`sepfm_ros.geometry.compiled`: a long-running process calls :func:`warm_up` once at
start so its first frame does not compile (or load) anything.
"""

from __future__ import annotations

import time

import numpy as np

from sepfm_ros.geometry.compiled import warm_up as warm_up_geometry
from sepfm_ros.pipeline.features import match_descriptors


def warm_up() -> float:
    """Compile or load every kernel behind a frame pair: matching, then the estimator.

    Returns:
        Seconds spent.
    """
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 100, (16, 2))
    desc = rng.integers(0, 256, (16, 32), dtype=np.uint8)  # ORB-like binary descriptors
    match_descriptors(pts, desc, pts, desc, features="orb")
    warm_up_geometry()
    return time.perf_counter() - t0
