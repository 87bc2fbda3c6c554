"""Putative matches for the evaluation, computed once per pair and cached as ``.npz``.

Matches come from :func:`sepfm_ros.pipeline.features.match_images` (the package's one matcher).
A cache file is keyed by the SHA-256 of both images' file contents plus the match settings, so a
changed image or setting never reuses stale matches, and renaming or moving images keeps the cache.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from sepfm_ros.evaluation.manifest import PairDataError, PairSpec
from sepfm_ros.pipeline.features import (
    FEATURES,
    Matches,
    match_images,
    unavailable_reason,
    unique_matches,
)

#: Bumped when the cached content or its meaning changes.
CACHE_VERSION = 1


@dataclass(frozen=True)
class MatchSettings:
    """How putative matches are made.

    Attributes:
        features: "sift" (default, as the paper), "orb" or "akaze".
        ratio: Lowe ratio-test threshold (the paper's Strecha runs used 0.75; the shared data's
            validation used 0.8).
        max_features: detector feature cap; 0 means the detector's own (unlimited for SIFT,
            2000 for ORB; AKAZE has no cap).
    """

    features: str = "sift"
    ratio: float = 0.8
    max_features: int = 0

    def __post_init__(self) -> None:
        if self.features not in FEATURES:
            raise ValueError(f"unknown features {self.features!r}; expected one of {FEATURES}")
        if not 0.0 < self.ratio <= 1.0:
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio}")
        if self.max_features < 0:
            raise ValueError(f"max_features must be >= 0, got {self.max_features}")
        reason = unavailable_reason(self.features)
        if reason is not None:
            raise ValueError(reason)

    def detector_cap(self) -> int:
        """The ``max_features`` passed to match_images."""
        if self.max_features:
            return self.max_features
        return 2000 if self.features == "orb" else 0


@dataclass
class PairMatches:
    """Matches of one pair: pts (N, 2) float64 in image a / b, sizes (width, height)."""

    pts_a: np.ndarray
    pts_b: np.ndarray
    size_a: tuple[int, int]
    size_b: tuple[int, int]
    from_cache: bool = False


def file_hash(path: Path) -> str:
    """SHA-256 hex digest of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def cache_key(hash_a: str, hash_b: str, settings: MatchSettings) -> str:
    """Cache file stem for two image hashes and the settings."""
    blob = json.dumps({"v": CACHE_VERSION, "a": hash_a, "b": hash_b, **asdict(settings)})
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def read_image(path: Path) -> np.ndarray:
    """Read an image file as stored (grey or BGR); PairDataError when it cannot be decoded."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise PairDataError(f"cannot read image {path} (missing, unreadable or not an image)")
    return img


def _size(img: np.ndarray) -> tuple[int, int]:
    return int(img.shape[1]), int(img.shape[0])


class MatchesCache:
    """Matches per pair, from ``folder`` when cached there, else computed and stored.

    ``folder=None`` disables caching (matches are computed every time).
    """

    def __init__(self, folder: str | Path | None, settings: MatchSettings | None = None):
        self.folder = Path(folder) if folder is not None else None
        self.settings = settings or MatchSettings()
        if self.folder is not None:
            self.folder.mkdir(parents=True, exist_ok=True)

    def matches(self, pair: PairSpec) -> PairMatches:
        """Distinct matches of ``pair``, best first (points entries as given, not cached).

        Repeated correspondences are dropped (``features.unique_matches``): SIFT reports a
        location once per orientation, and the estimators reject duplicates.
        """
        pm = self._raw_matches(pair)
        m = unique_matches(Matches(pm.pts_a, pm.pts_b, np.zeros(len(pm.pts_a))))
        pm.pts_a, pm.pts_b = m.pts_a, m.pts_b
        return pm

    def _raw_matches(self, pair: PairSpec) -> PairMatches:
        if pair.pts_a is not None and pair.pts_b is not None:
            assert pair.size_a is not None
            return PairMatches(pair.pts_a, pair.pts_b, pair.size_a, pair.size_b or pair.size_a)
        assert pair.img_a is not None and pair.img_b is not None
        for p in (pair.img_a, pair.img_b):
            if not p.is_file():
                raise PairDataError(f"image not found: {p}")
        path = None
        if self.folder is not None:
            key = cache_key(file_hash(pair.img_a), file_hash(pair.img_b), self.settings)
            path = self.folder / f"{key}.npz"
            if path.is_file():
                try:
                    with np.load(path) as z:
                        return PairMatches(
                            z["pts_a"],
                            z["pts_b"],
                            tuple(int(v) for v in z["size_a"]),
                            tuple(int(v) for v in z["size_b"]),
                            from_cache=True,
                        )
                except (OSError, ValueError, KeyError):
                    pass  # a corrupt cache file is recomputed and overwritten
        img_a, img_b = read_image(pair.img_a), read_image(pair.img_b)
        s = self.settings
        m = match_images(img_a, img_b, s.features, s.detector_cap(), s.ratio)
        result = PairMatches(m.pts_a, m.pts_b, _size(img_a), _size(img_b))
        if path is not None:
            fd, tmp = tempfile.mkstemp(suffix=".npz", dir=path.parent)
            with os.fdopen(fd, "wb") as f:
                np.savez(
                    f,
                    pts_a=result.pts_a,
                    pts_b=result.pts_b,
                    ratio=m.ratio,
                    size_a=np.array(result.size_a),
                    size_b=np.array(result.size_b),
                )
            os.replace(tmp, path)
        return result
