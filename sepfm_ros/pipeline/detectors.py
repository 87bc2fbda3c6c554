"""The feature detectors the pipeline offers (OpenCV's ORB, SIFT, AKAZE) and whether this
environment's ``cv2`` has each, naming the fix when it does not. No ROS, no compiled kernels."""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from importlib import metadata

import cv2

FEATURES = ("orb", "sift", "akaze")


# The PyPI wheels that each install a ``cv2`` (OpenCV's packaging notes: install only one).
OPENCV_WHEELS = (
    "opencv-python",
    "opencv-python-headless",
    "opencv-contrib-python",
    "opencv-contrib-python-headless",
)


def make_detector(features: str = "orb", max_features: int = 1000) -> cv2.Feature2D:
    """Create an OpenCV detector/descriptor: ``orb``, ``sift`` or ``akaze``.

    Raises:
        ValueError: unknown ``features``, or ``akaze`` with a ``cv2`` that lacks AKAZE (the
            message names the fix, see :func:`unavailable_reason`).
    """
    if features == "orb":
        return cv2.ORB.create(nfeatures=int(max_features))
    if features == "sift":
        return cv2.SIFT.create(nfeatures=int(max_features) if max_features else 0)
    if features == "akaze":
        create = _akaze_factory()
        if create is None:
            raise ValueError(_akaze_missing())
        return create()
    raise ValueError(f"unknown features {features!r}; expected one of {FEATURES}")


@cache
def unavailable_reason(features: str) -> str | None:
    """Why this environment's ``cv2`` cannot create the ``features`` detector, naming the fix;
    None when it can."""
    try:
        make_detector(features, 100)
    except (AttributeError, ValueError, cv2.error) as e:
        return str(e)
    return None


def detector_available(features: str) -> bool:
    """True when this environment's ``cv2`` can create the ``features`` detector."""
    return unavailable_reason(features) is None


def available_features() -> tuple[str, ...]:
    """The detectors of :data:`FEATURES` this environment's ``cv2`` has (AKAZE only with it)."""
    return tuple(f for f in FEATURES if detector_available(f))


def _akaze_factory() -> Callable[[], cv2.Feature2D] | None:
    """AKAZE's constructor: OpenCV 4's main module has it, OpenCV 5 only the contrib module
    ``xfeatures2d`` (the opencv-contrib-python wheels); None without either."""
    return getattr(cv2, "AKAZE_create", None) or getattr(
        getattr(cv2, "xfeatures2d", None), "AKAZE_create", None
    )


def _akaze_missing() -> str:
    """The error for ``akaze`` without AKAZE: what this ``cv2`` is and how to get one with it."""
    wheels = [
        f"{name} {version}"
        for name in OPENCV_WHEELS
        if (version := _installed_version(name)) is not None
    ]
    installed = ", ".join(wheels) if wheels else f"no OpenCV wheel, cv2 from {cv2.__file__}"
    remove = " ".join(w.split()[0] for w in wheels)
    fix = "pip install opencv-contrib-python-headless"
    if remove:
        fix = f"pip uninstall -y {remove} && {fix}"
    return (
        f"features 'akaze' need AKAZE, which this environment's OpenCV {cv2.__version__} "
        f"({installed}) does not have: OpenCV 5 ships it only in its contrib wheel. "
        f"Fix: {fix} (only one OpenCV wheel per environment: each overwrites the others' cv2), "
        "or use features 'orb' or 'sift'"
    )


def _installed_version(distribution: str) -> str | None:
    """The installed version of a PyPI distribution, None when it is not installed."""
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return None
