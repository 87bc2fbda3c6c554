"""ROS-free core: the paper's separable two-stage fundamental-matrix estimator and baselines.

Public API::

    estimate_fundamental(pts1, pts2, image_size1, image_size2=None, method=DEFAULT_METHOD,
                         threshold=1.0, confidence=0.99, seed=None, options=None,
                         **kwargs) -> Estimate

with ``DEFAULT_METHOD`` the best-measured method (``"sep4"``), ``options`` an
:class:`EstimatorOptions` and ``kwargs`` fields of it replacing its values,
and the helpers :func:`symmetric_epipolar_distance`, :func:`sampson_distance`,
:func:`fundamental_from_cameras` and :func:`ransac_trials` (the paper's F(k, r)).
No module below this package imports ROS.
"""

from sepfm_ros.geometry.epipolar import (
    fundamental_from_cameras,
    normalize_fundamental,
    sampson_distance,
    symmetric_epipolar_distance,
)
from sepfm_ros.geometry.estimate import Estimate, StatusCode
from sepfm_ros.geometry.estimator import DEFAULT_METHOD, METHODS, estimate_fundamental
from sepfm_ros.geometry.options import EstimatorOptions
from sepfm_ros.geometry.robust.trials import ransac_trials

__all__ = [
    "DEFAULT_METHOD",
    "METHODS",
    "Estimate",
    "EstimatorOptions",
    "estimate_fundamental",
    "fundamental_from_cameras",
    "normalize_fundamental",
    "StatusCode",
    "ransac_trials",
    "sampson_distance",
    "symmetric_epipolar_distance",
]
