"""Feature detection and matching (OpenCV), matches sorted best first.

This is the one place the package turns two images into putative correspondences; the node,
offline bag processing, evaluation and the tests all call :func:`match_images`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

FEATURES = ("orb", "sift", "akaze")


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


def make_detector(features: str = "orb", max_features: int = 1000) -> cv2.Feature2D:
    """Create an OpenCV detector/descriptor: ``orb``, ``sift`` or ``akaze``."""
    if features == "orb":
        return cv2.ORB_create(nfeatures=int(max_features))
    if features == "sift":
        return cv2.SIFT_create(nfeatures=int(max_features) if max_features else 0)
    if features == "akaze":
        if not hasattr(cv2, "AKAZE_create"):
            raise ValueError(
                f"features 'akaze' are not available in this OpenCV build ({cv2.__version__})"
            )
        return cv2.AKAZE_create()
    raise ValueError(f"unknown features {features!r}; expected one of {FEATURES}")


def _norm_for(features: str) -> int:
    return cv2.NORM_HAMMING if features in ("orb", "akaze") else cv2.NORM_L2


def to_gray(image: np.ndarray) -> np.ndarray:
    """Return an 8-bit single-channel view of ``image`` (H, W) or (H, W, 3|4) BGR(A)."""
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    if image.dtype != np.uint8:
        image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return image


def detect(image: np.ndarray, detector: cv2.Feature2D) -> tuple[np.ndarray, np.ndarray | None]:
    """Detect keypoints and descriptors: returns ((K, 2) float64 points, (K, D) descriptors)."""
    kps, desc = detector.detectAndCompute(to_gray(image), None)
    pts = np.array([kp.pt for kp in kps], dtype=np.float64).reshape(-1, 2)
    return pts, desc


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
    matcher = cv2.BFMatcher(_norm_for(features))
    knn = matcher.knnMatch(desc_a, desc_b, k=2)
    ia, ib, rr = [], [], []
    for pair in knn:
        if len(pair) < 2:
            continue
        m, n = pair
        r = m.distance / n.distance if n.distance > 0 else (0.0 if m.distance == 0 else 1.0)
        if r < ratio:
            ia.append(m.queryIdx)
            ib.append(m.trainIdx)
            rr.append(r)
    if not ia:
        return empty
    ia, ib, rr = np.asarray(ia), np.asarray(ib), np.asarray(rr, dtype=np.float64)
    order = np.argsort(rr, kind="stable")
    ia, ib, rr = ia[order], ib[order], rr[order]
    # keep the best match per point in image b (one-to-one on b's side), then drop repeated
    # correspondences (SIFT reports a keypoint once per dominant orientation)
    _, first = np.unique(ib, return_index=True)
    keep = np.sort(first)
    pa, pb, rr = pts_a[ia[keep]], pts_b[ib[keep]], rr[keep]
    _, first = np.unique(np.concatenate([pa, pb], axis=1), axis=0, return_index=True)
    keep = np.sort(first)
    return Matches(pa[keep], pb[keep], rr[keep])


def match_images(
    image_a: np.ndarray,
    image_b: np.ndarray,
    features: str = "orb",
    max_features: int = 1000,
    ratio: float = 0.8,
) -> Matches:
    """Detect, describe and match two images; matches sorted best (lowest ratio) first."""
    detector = make_detector(features, max_features)
    pts_a, desc_a = detect(image_a, detector)
    pts_b, desc_b = detect(image_b, detector)
    return match_descriptors(pts_a, desc_a, pts_b, desc_b, features=features, ratio=ratio)
