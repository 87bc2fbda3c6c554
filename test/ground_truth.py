"""Ground-truth helpers shared by the pipeline and node tests (real images of ../shared/data)."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import numpy as np

from sepfm_ros.evaluation.manifest import PairSpec, load_manifest
from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings, PairMatches
from sepfm_ros.evaluation.metrics import positives
from sepfm_ros.geometry import fundamental_from_cameras, symmetric_epipolar_distance

REPO_ROOT = Path(__file__).resolve().parent.parent

GT_INLIER_PX = 1.0  # a match is a GT inlier when its symmetric epipolar distance under GT F < 1 px


@cache
def _cameras(data: Path) -> dict:
    return json.loads((data / "cameras.json").read_text())


def gt_fundamental(data: Path, img_a: str, img_b: str) -> np.ndarray:
    """GT F (x_b^T F x_a = 0) from cameras.json, for images given relative to ``data``."""
    cams = _cameras(data)
    return fundamental_from_cameras(np.asarray(cams[img_a]), np.asarray(cams[img_b]))


def median_gt_inlier_error(
    F: np.ndarray, F_gt: np.ndarray, pts_a: np.ndarray, pts_b: np.ndarray
) -> tuple[float, int]:
    """(median symmetric epipolar error under F of the GT-inlier matches, their count)."""
    gt_inliers = symmetric_epipolar_distance(F_gt, pts_a, pts_b) < GT_INLIER_PX
    n = int(np.count_nonzero(gt_inliers))
    if n == 0:
        return float("inf"), 0
    errors = symmetric_epipolar_distance(F, pts_a[gt_inliers], pts_b[gt_inliers])
    return float(np.median(errors)), n


def manifest_pair(
    data: Path, pair_id: str, ratio: float
) -> tuple[PairSpec, PairMatches, np.ndarray]:
    """The pair ``pair_id`` of ``data``/pairs.json, its SIFT matches at ``ratio`` (cached in
    .cache/matches) and their GT positives, (N,) bool."""
    pairs, _ = load_manifest(data / "pairs.json")
    pair = next(p for p in pairs if p.pair_id == pair_id)
    m = MatchesCache(REPO_ROOT / ".cache" / "matches", MatchSettings("sift", ratio)).matches(pair)
    return pair, m, positives(pair.F_gt, m.pts_a, m.pts_b)
