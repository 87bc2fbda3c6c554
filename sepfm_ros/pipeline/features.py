"""Feature detection and matching (OpenCV), matches sorted best first.

This is the one place the package turns two images into putative correspondences; the node,
offline bag processing, evaluation and the tests all call :func:`match_images`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import cv2
import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.core.extending import intrinsic

from sepfm_ros.pipeline.detectors import (  # the detectors the pipeline offers
    FEATURES,
    available_features,
    detector_available,
    make_detector,
    unavailable_reason,
)

__all__ = [
    "FEATURES",
    "Matches",
    "available_features",
    "detect",
    "detector_available",
    "detection_factor",
    "make_detector",
    "match_descriptors",
    "match_images",
    "to_full_resolution",
    "to_gray",
    "unavailable_reason",
    "unique_matches",
]


@dataclass(frozen=True)
class Matches:
    """Putative correspondences between image a and image b.

    Attributes:
        pts_a: (N, 2) float64 pixel coordinates in image a (OpenCV keypoint convention).
        pts_b: (N, 2) float64 pixel coordinates in image b.
        ratio: (N,) float64 Lowe ratio (best / second-best descriptor distance), ascending:
            matches are sorted best first.
    """

    pts_a: np.ndarray
    pts_b: np.ndarray
    ratio: np.ndarray

    def __len__(self) -> int:
        return int(self.pts_a.shape[0])


def _norm_for(features: str) -> int:
    return cv2.NORM_HAMMING if features in ("orb", "akaze") else cv2.NORM_L2


def to_gray(image: np.ndarray) -> np.ndarray:
    """Return an 8-bit single-channel view of ``image`` (H, W) or (H, W, 3|4) BGR(A)."""
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    if image.dtype != np.uint8:
        scaled = cv2.normalize(image, np.empty_like(image), 0, 255, cv2.NORM_MINMAX)
        image = np.asarray(scaled).astype(np.uint8)
    return image


def detection_factor(width: int, max_width: int) -> int:
    """The integer factor s >= 1 an image ``width`` px wide is downscaled by for detection:
    ceil(width / max_width) when width > max_width > 0, else 1 (no downscale)."""
    if max_width <= 0 or width <= max_width:
        return 1
    return -(-int(width) // int(max_width))


def downscaled(gray: np.ndarray, factor: int) -> tuple[np.ndarray, tuple[float, float]]:
    """``gray`` (H, W) resized by 1 / ``factor`` with ``cv2.INTER_AREA`` (box average).

    Returns:
        (the (ceil(H / factor), ceil(W / factor)) image, (s_x, s_y)) with s_x = W / w and
        s_y = H / h: exactly ``factor`` when it divides the size, otherwise the scale OpenCV
        used on that axis (:func:`to_full_resolution` maps points back with it).
    """
    height, width = gray.shape[:2]
    w, h = -(-width // factor), -(-height // factor)
    small = cv2.resize(gray, (w, h), interpolation=cv2.INTER_AREA)
    return small, (width / w, height / h)


def to_full_resolution(pts: np.ndarray, scale: tuple[float, float]) -> np.ndarray:
    """(K, 2) pixel coordinates in an image resized by 1 / scale -> the original image's pixels.

    Pixel centres are at integer coordinates (OpenCV's keypoint convention); ``cv2.resize``
    maps the source to the destination pixel centre to centre, x_small = (x + 0.5) / s - 0.5,
    so x = (x_small + 0.5) * s - 0.5 on each axis (``scale`` = (s_x, s_y)).
    """
    return (np.asarray(pts, dtype=np.float64) + 0.5) * np.asarray(scale, dtype=np.float64) - 0.5


def detect(
    image: np.ndarray, detector: cv2.Feature2D, max_width: int = 0
) -> tuple[np.ndarray, np.ndarray | None]:
    """Detect keypoints and descriptors: returns ((K, 2) float64 points, (K, D) descriptors).

    An image wider than ``max_width`` (> 0) is detected on a copy downscaled by the integer
    factor :func:`detection_factor` (``cv2.INTER_AREA``); the points are then mapped back to
    ``image``'s pixels (:func:`to_full_resolution`). ``max_width`` 0: always at full size.
    """
    gray = to_gray(image)
    factor = detection_factor(gray.shape[1], max_width)
    scale = (1.0, 1.0)
    if factor > 1:
        gray, scale = downscaled(gray, factor)
    kps, desc = detector.detectAndCompute(gray, None)
    pts = (
        np.asarray(cv2.KeyPoint.convert(kps), dtype=np.float64).reshape(-1, 2)
        if kps
        else np.zeros((0, 2))
    )
    if factor > 1:
        pts = to_full_resolution(pts, scale)
    return pts, desc


@intrinsic
def _popcount64(typingctx: Any, x: Any) -> tuple[Any, Callable[..., Any]]:
    """Set bits of a uint64 (LLVM's ctpop: one POPCNT, or a vector popcount in a vector loop)."""
    sig = types.uint64(types.uint64)

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        fn = builder.module.declare_intrinsic("llvm.ctpop", [ir.IntType(64)])
        return builder.call(fn, args)

    return sig, codegen


#: the intrinsic as numba code calls it (one uint64 -> its set bits); its Python signature is the
#: typing hook's (typingctx, x)
_popcount = cast(Callable[[Any], Any], _popcount64)


@numba.njit(cache=True, nogil=True)
def _two_nearest_hamming(
    words_a: np.ndarray, words_b_t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Kernel of :func:`_two_nearest_binary`: (Na, W) uint64 words of a, (W, Nb) of b, Nb >= 2.

    b is transposed (one row per word) so the distance loop over b runs over contiguous words
    and LLVM vectorises it (AVX2: four distances per instruction); the scan for the two
    smallest follows. About 3x faster than one scalar distance at a time.
    """
    n_a, n_words = words_a.shape
    n_b = words_b_t.shape[1]
    i1 = np.empty(n_a, dtype=np.int64)
    i2 = np.empty(n_a, dtype=np.int64)
    d1 = np.empty(n_a, dtype=np.int64)
    d2 = np.empty(n_a, dtype=np.int64)
    dist = np.empty(n_b, dtype=np.uint64)
    far = np.uint64(1) << np.uint64(62)
    for i in range(n_a):
        a_word = words_a[i, 0]
        b_words = words_b_t[0]
        for j in range(n_b):
            dist[j] = _popcount(a_word ^ b_words[j])
        for w in range(1, n_words):
            a_word = words_a[i, w]
            b_words = words_b_t[w]
            for j in range(n_b):
                dist[j] += _popcount(a_word ^ b_words[j])
        best, second = far, far
        j_best, j_second = 0, 0
        for j in range(n_b):
            d = dist[j]
            # strict comparisons: among equal distances the lower index wins both places
            if d < second:
                if d < best:
                    second, j_second = best, j_best
                    best, j_best = d, j
                else:
                    second, j_second = d, j
        i1[i], d1[i], i2[i], d2[i] = j_best, best, j_second, second
    return i1, d1, i2, d2


def _as_words(desc: np.ndarray, n_words: int) -> np.ndarray:
    """(N, B) uint8 packed bits -> (N, n_words) uint64, zero-padded (padding adds no distance)."""
    if desc.shape[1] == 8 * n_words:
        return np.ascontiguousarray(desc).view(np.uint64)
    padded = np.zeros((len(desc), 8 * n_words), dtype=np.uint8)
    padded[:, : desc.shape[1]] = desc
    return padded.view(np.uint64)


def _two_nearest_binary(
    desc_a: np.ndarray, desc_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Two nearest b-descriptors of every a-descriptor under the Hamming distance.

    Exact brute force with a popcount per 64 bits (vectorised), compiled (numba) and without the
    GIL, so the node's estimate thread keeps running meanwhile. Ties go to the lower index, as
    in OpenCV's brute-force matcher (``BFMatcher.knnMatch``, whose results these equal).

    Args:
        desc_a: (Na, B) uint8 packed binary descriptors; desc_b: (Nb, B), Nb >= 2.
    Returns:
        (i1, d1, i2, d2): (Na,) indices into desc_b and Hamming distances (float64) of the
        nearest and second-nearest descriptor.
    """
    n_words = -(-desc_a.shape[1] // 8)
    words_b_t = np.ascontiguousarray(_as_words(desc_b, n_words).T)
    i1, d1, i2, d2 = _two_nearest_hamming(_as_words(desc_a, n_words), words_b_t)
    return i1, d1.astype(np.float64), i2, d2.astype(np.float64)


def _two_nearest(
    desc_a: np.ndarray, desc_b: np.ndarray, features: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(i1, d1, i2, d2) of :func:`_two_nearest_binary` for any descriptor type.

    Binary descriptors (uint8, Hamming) take the exact product above; float descriptors (SIFT,
    L2) take OpenCV's brute-force k-nearest search (the same as ``BFMatcher.knnMatch``).
    """
    if _norm_for(features) == cv2.NORM_HAMMING and desc_a.dtype == np.uint8:
        return _two_nearest_binary(desc_a, desc_b)
    dist, idx = cv2.batchDistance(desc_a, desc_b, cv2.CV_32F, normType=_norm_for(features), K=2)
    dist = dist.astype(np.float64)
    return idx[:, 0].astype(np.int64), dist[:, 0], idx[:, 1].astype(np.int64), dist[:, 1]


def match_descriptors(
    pts_a: np.ndarray,
    desc_a: np.ndarray | None,
    pts_b: np.ndarray,
    desc_b: np.ndarray | None,
    features: str = "orb",
    ratio: float = 0.8,
) -> Matches:
    """Brute-force 2-NN matching with Lowe's ratio test, one match per point of b, best first."""
    empty = Matches(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    if desc_a is None or desc_b is None or len(desc_a) < 2 or len(desc_b) < 2:
        return empty
    i1, d1, i2, d2 = _two_nearest(
        np.ascontiguousarray(desc_a), np.ascontiguousarray(desc_b), features
    )
    del i2  # only the second distance matters for the ratio test
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(d2 > 0, d1 / d2, np.where(d1 == 0, 0.0, 1.0))
    ia = np.flatnonzero(r < ratio)
    if not len(ia):
        return empty
    ib, rr = i1[ia], r[ia]
    order = np.argsort(rr, kind="stable")
    ia, ib, rr = ia[order], ib[order], rr[order]
    # keep the best match per point in image b (one-to-one on b's side), then drop repeated
    # correspondences
    _, first = np.unique(ib, return_index=True)
    keep = np.sort(first)
    return unique_matches(Matches(pts_a[ia[keep]], pts_b[ib[keep]], rr[keep]))


def unique_matches(matches: Matches) -> Matches:
    """Drop repeated correspondences (same pts_a and pts_b), keeping the first (best) of each.

    SIFT can return one location several times (one per orientation); estimators reject
    duplicate correspondences, and they carry no information.
    """
    if len(matches) < 2:
        return matches
    both = np.concatenate([matches.pts_a, matches.pts_b], axis=1)
    _, first = np.unique(both, axis=0, return_index=True)
    if len(first) == len(matches):
        return matches
    keep = np.sort(first)
    return Matches(matches.pts_a[keep], matches.pts_b[keep], matches.ratio[keep])


def match_images(
    image_a: np.ndarray,
    image_b: np.ndarray,
    features: str = "orb",
    max_features: int = 1000,
    ratio: float = 0.8,
    max_width: int = 0,
) -> Matches:
    """Detect, describe and match two images; matches sorted best (lowest ratio) first.

    ``max_width``: detect on a downscaled copy of an image wider than this (see :func:`detect`;
    0 = full size, the default here); the matches are in the images' own pixels either way.
    """
    detector = make_detector(features, max_features)
    pts_a, desc_a = detect(image_a, detector, max_width)
    pts_b, desc_b = detect(image_b, detector, max_width)
    return match_descriptors(pts_a, desc_a, pts_b, desc_b, features=features, ratio=ratio)
