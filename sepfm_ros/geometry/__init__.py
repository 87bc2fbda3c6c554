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

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sepfm_ros.geometry.epipolar import (
        fundamental_from_cameras,
        normalize_fundamental,
        sampson_distance,
        symmetric_epipolar_distance,
    )
    from sepfm_ros.geometry.estimate import Estimate, StatusCode
    from sepfm_ros.geometry.estimator import estimate_fundamental
    from sepfm_ros.geometry.options import DEFAULT_METHOD, METHODS, EstimatorOptions
    from sepfm_ros.geometry.robust.trials import ransac_trials

#: public name -> the module defining it; imported on first use, so that importing a light
#: module of this package (its options, say) does not compile or load the estimator's kernels
_HOME = {
    "DEFAULT_METHOD": "options",
    "METHODS": "options",
    "EstimatorOptions": "options",
    "Estimate": "estimate",
    "StatusCode": "estimate",
    "estimate_fundamental": "estimator",
    "fundamental_from_cameras": "epipolar",
    "normalize_fundamental": "epipolar",
    "sampson_distance": "epipolar",
    "symmetric_epipolar_distance": "epipolar",
    "ransac_trials": "robust.trials",
}


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value


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
