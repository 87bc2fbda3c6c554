"""Every metric of the evaluation report, defined in this one place (the paper's Sec. 6 rules).

Definitions (all distances in pixels of the stored images, ``x_b^T F x_a = 0``):

- **Symmetric epipolar distance** of a match under F: the mean of its two point-to-epipolar-line
  distances (:func:`sepfm_ros.geometry.symmetric_epipolar_distance`).
- **Positive**: a putative match whose symmetric epipolar distance under the *ground-truth* F is
  below :data:`POSITIVE_PX` (1 px). Positives are the reference set every method is scored against.
- **Inlier mask** of a method: the matches whose symmetric epipolar distance under the method's
  *estimated* F is below the run's threshold. It is recomputed here from the returned F for every
  method (OpenCV thresholds the larger of the two point-line distances, PoseLib the Sampson error),
  so that one threshold means the same thing for all methods. No F -> no inliers.
- **% inliers**: 100 * inliers / matches.
- **F-score**: the harmonic mean of precision (positives among inliers / inliers) and recall
  (positives among inliers / positives) of the inlier mask; 0 when no positive is recovered.
  Tables show its mean and standard deviation over runs (pair x seed).
- **Mean / median error**: the mean and the median symmetric epipolar distance of the positives
  under the *estimated* F, per run; the tables show the mean over runs of the per-run mean and the
  median over runs of the per-run median. Runs without an F have no error (NaN, left out) and are
  counted as failures.
- **Failure** (the paper's rule): a run that recovers fewer than :data:`MIN_RECOVERED_POSITIVES`
  (20) positives as inliers, on a pair that has at least 20 positives; pairs with fewer than 20
  positives are not *evaluable* and are left out of the failure rate (the paper discards them).
- **Hypotheses**: models scored, reported only where a method exposes the count: stage 1 (line
  homographies H_e scored on the line points) and stage 2 (F models scored against all matches)
  apart for ours; PoseLib exposes its RANSAC iterations (samples). OpenCV does not expose a count,
  so its hypotheses are n/a, never estimated.
- **ms per pair**: wall-clock milliseconds of the estimator call on the cached matches (matching
  time is not included; it is the same for all methods).
- **Paired comparison** against a named baseline: per pair the metric is averaged over seeds; a
  method *wins* a pair when it is better by more than a tie tolerance. Reported: wins, losses,
  ties, the fraction of decided pairs won with a Wilson score interval, the two-sided exact sign
  test p-value, and the mean difference with a seeded paired-bootstrap interval. A table difference
  whose win-fraction interval contains 0.5 is not distinguishable from noise on this data.
- **Line homography error** (the paper's Fig. 8): for a match (x_a, x_b) on the line pair
  (l_a, l_b), projected onto the lines, the symmetric transfer error along the lines of the
  epipolar homography H_e that F induces (:func:`line_homography_error`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from sepfm_ros.geometry import symmetric_epipolar_distance

#: A match is a positive when its symmetric epipolar distance under the GT F is below this (px).
POSITIVE_PX = 1.0
#: A run fails when fewer positives than this are recovered as inliers (paper, Sec. 6.4).
MIN_RECOVERED_POSITIVES = 20


def positives(F_gt: np.ndarray, pts_a: np.ndarray, pts_b: np.ndarray) -> np.ndarray:
    """(N,) bool: matches within :data:`POSITIVE_PX` of the ground truth F_gt (3, 3)."""
    return symmetric_epipolar_distance(F_gt, pts_a, pts_b) < POSITIVE_PX


def inlier_mask(
    F: np.ndarray | None, pts_a: np.ndarray, pts_b: np.ndarray, threshold: float
) -> np.ndarray:
    """(N,) bool: matches whose symmetric epipolar distance under F is below ``threshold`` px."""
    if F is None:
        return np.zeros(pts_a.shape[0], dtype=bool)
    return symmetric_epipolar_distance(F, pts_a, pts_b) < threshold


def f_score(predicted: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    """(precision, recall, F-score) of a predicted bool mask against a true bool mask.

    Precision is 0 for an empty prediction, recall is 0 for an empty truth, and the F-score is 0
    when there is no true positive.
    """
    predicted = np.asarray(predicted, dtype=bool)
    truth = np.asarray(truth, dtype=bool)
    tp = int(np.count_nonzero(predicted & truth))
    n_pred = int(np.count_nonzero(predicted))
    n_true = int(np.count_nonzero(truth))
    precision = tp / n_pred if n_pred else 0.0
    recall = tp / n_true if n_true else 0.0
    f = 2.0 * precision * recall / (precision + recall) if tp else 0.0
    return precision, recall, f


@dataclass(frozen=True)
class RunMetrics:
    """Metrics of one estimator run (one method, one seed) on one pair. See the module doc."""

    n_matches: int
    n_positives: int
    n_inliers: int
    true_positives: int
    pct_inliers: float
    precision: float
    recall: float
    f_score: float
    mean_error: float  # px, NaN without F or without positives
    median_error: float  # px, NaN without F or without positives
    evaluable: bool  # the pair has >= MIN_RECOVERED_POSITIVES positives
    failed: bool  # evaluable and fewer than MIN_RECOVERED_POSITIVES positives recovered

    @property
    def succeeded(self) -> bool:
        """The benchmarks' success: an F whose median error on the GT positives is below 1 px
        and that recovered enough of them (not ``failed``); False without F (NaN error)."""
        return bool(self.median_error < 1.0 and not self.failed)


def run_metrics(
    F: np.ndarray | None,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    positive: np.ndarray,
    threshold: float,
) -> RunMetrics:
    """Score an estimate F (3, 3) or None on matches (N, 2) x2 with GT positives (N,) bool."""
    n = int(pts_a.shape[0])
    inl = inlier_mask(F, pts_a, pts_b, threshold)
    precision, recall, f = f_score(inl, positive)
    tp = int(np.count_nonzero(inl & positive))
    n_pos = int(np.count_nonzero(positive))
    if F is not None and n_pos:
        err = symmetric_epipolar_distance(F, pts_a[positive], pts_b[positive])
        mean_err, median_err = float(np.mean(err)), float(np.median(err))
    else:
        mean_err = median_err = math.nan
    evaluable = n_pos >= MIN_RECOVERED_POSITIVES
    return RunMetrics(
        n_matches=n,
        n_positives=n_pos,
        n_inliers=int(np.count_nonzero(inl)),
        true_positives=tp,
        pct_inliers=100.0 * np.count_nonzero(inl) / n if n else 0.0,
        precision=precision,
        recall=recall,
        f_score=f,
        mean_error=mean_err,
        median_error=median_err,
        evaluable=evaluable,
        failed=evaluable and tp < MIN_RECOVERED_POSITIVES,
    )


def _mean(values: list[float]) -> float:
    v = [x for x in values if x is not None and not math.isnan(x)]
    return float(np.mean(v)) if v else math.nan


@dataclass(frozen=True)
class Summary:
    """Aggregate of runs of one method (over pairs x seeds). Hypotheses are None when n/a."""

    method: str
    runs: int
    pairs: int
    pct_inliers: float
    f_score_mean: float
    f_score_std: float
    mean_error: float
    median_error: float
    failure_pct: float  # % of evaluable runs that failed
    no_model: int  # runs that returned no F
    hypotheses: float | None
    stage1_hypotheses: float | None
    stage2_hypotheses: float | None
    ms_mean: float
    ms_median: float


def summarize(method: str, runs: list[dict]) -> Summary:
    """Aggregate per-run records (dicts with the :class:`RunMetrics` fields plus ``pair``,
    ``has_model``, ``hypotheses``, ``stage1_hypotheses``, ``stage2_hypotheses`` (None when n/a)
    and ``ms``) of one method into one table row."""
    if not runs:
        nan = math.nan
        return Summary(method, 0, 0, nan, nan, nan, nan, nan, nan, 0, None, None, None, nan, nan)
    f = np.array([r["f_score"] for r in runs], dtype=np.float64)
    medians = [r["median_error"] for r in runs if not math.isnan(r["median_error"])]
    evaluable = [r for r in runs if r["evaluable"]]

    def hyp(key: str) -> float | None:
        vals = [r[key] for r in runs if r.get(key) is not None]
        return float(np.mean(vals)) if vals and len(vals) == len(runs) else None

    ms = np.array([r["ms"] for r in runs], dtype=np.float64)
    return Summary(
        method=method,
        runs=len(runs),
        pairs=len({r["pair"] for r in runs}),
        pct_inliers=_mean([r["pct_inliers"] for r in runs]),
        f_score_mean=float(f.mean()),
        f_score_std=float(f.std()),
        mean_error=_mean([r["mean_error"] for r in runs]),
        median_error=float(np.median(medians)) if medians else math.nan,
        failure_pct=(
            100.0 * sum(r["failed"] for r in evaluable) / len(evaluable) if evaluable else math.nan
        ),
        no_model=sum(not r["has_model"] for r in runs),
        hypotheses=hyp("hypotheses"),
        stage1_hypotheses=hyp("stage1_hypotheses"),
        stage2_hypotheses=hyp("stage2_hypotheses"),
        ms_mean=float(ms.mean()),
        ms_median=float(np.median(ms)),
    )


def wilson_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion; (nan, nan) for zero trials."""
    if trials <= 0:
        return math.nan, math.nan
    z = NormalDist().inv_cdf(0.5 + confidence / 2.0)
    p = successes / trials
    den = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / den
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / den
    return max(0.0, centre - half), min(1.0, centre + half)


def sign_test_p(wins: int, losses: int) -> float:
    """Two-sided exact sign-test p-value for ``wins`` vs ``losses`` (ties dropped)."""
    n = wins + losses
    if n == 0:
        return 1.0
    k = min(wins, losses)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


@dataclass(frozen=True)
class PairedComparison:
    """A method against a baseline on the pairs both have a value for. See the module doc."""

    method: str
    baseline: str
    metric: str
    higher_is_better: bool
    pairs: int
    wins: int
    losses: int
    ties: int
    win_fraction: float  # wins / (wins + losses)
    win_ci: tuple[float, float]
    p_value: float
    mean_diff: float  # method - baseline (raw metric units)
    diff_ci: tuple[float, float]


def paired_comparison(
    method: str,
    baseline: str,
    metric: str,
    method_values: dict[str, float],
    baseline_values: dict[str, float],
    higher_is_better: bool = True,
    tie_tolerance: float = 1e-9,
    confidence: float = 0.95,
    seed: int = 0,
    n_bootstrap: int = 2000,
) -> PairedComparison:
    """Compare per-pair values (pair id -> value, already averaged over seeds) of two methods.

    Pairs missing or NaN on either side are left out.
    """
    keys = sorted(
        k
        for k in method_values.keys() & baseline_values.keys()
        if not (math.isnan(method_values[k]) or math.isnan(baseline_values[k]))
    )
    m = np.array([method_values[k] for k in keys], dtype=np.float64)
    b = np.array([baseline_values[k] for k in keys], dtype=np.float64)
    diff = m - b
    better = diff if higher_is_better else -diff
    wins = int(np.count_nonzero(better > tie_tolerance))
    losses = int(np.count_nonzero(better < -tie_tolerance))
    ties = len(keys) - wins - losses
    decided = wins + losses
    if len(keys):
        rng = np.random.default_rng(seed)
        idx = rng.integers(0, len(keys), size=(n_bootstrap, len(keys)))
        boot = diff[idx].mean(axis=1)
        alpha = (1.0 - confidence) / 2.0
        diff_ci = (float(np.quantile(boot, alpha)), float(np.quantile(boot, 1.0 - alpha)))
        mean_diff = float(diff.mean())
    else:
        diff_ci, mean_diff = (math.nan, math.nan), math.nan
    return PairedComparison(
        method=method,
        baseline=baseline,
        metric=metric,
        higher_is_better=higher_is_better,
        pairs=len(keys),
        wins=wins,
        losses=losses,
        ties=ties,
        win_fraction=wins / decided if decided else math.nan,
        win_ci=wilson_interval(wins, decided, confidence),
        p_value=sign_test_p(wins, losses),
        mean_diff=mean_diff,
        diff_ci=diff_ci,
    )


def project_to_line(line: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(M, 2) orthogonal projections of pts (M, 2) onto the line (a, b, c): a u + b v + c = 0."""
    a, b, c = (float(v) for v in line)
    k = (pts @ np.array([a, b]) + c) / (a * a + b * b)
    return pts - k[:, None] * np.array([a, b])


def _transfer(F: np.ndarray, line_to: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """|dst - (line_to x F src)| in px for src/dst (M, 2); inf where the lines are parallel."""
    x = np.concatenate([src, np.ones((src.shape[0], 1))], axis=1)
    p = np.cross(x @ F.T, np.asarray(line_to, dtype=np.float64)[None, :])
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = p[:, :2] / p[:, 2:3]
        d = np.hypot(uv[:, 0] - dst[:, 0], uv[:, 1] - dst[:, 1])
    return np.where(np.isfinite(d), d, np.inf)


def line_homography_error(
    F: np.ndarray, line_a: np.ndarray, line_b: np.ndarray, pts_a: np.ndarray, pts_b: np.ndarray
) -> np.ndarray:
    """(M,) px: symmetric transfer error, along the line pair, of the H_e that F induces.

    The matches (pts_a, pts_b: (M, 2)) are first projected onto line_a / line_b (3,) (lines
    ``a u + b v + c = 0``), as the estimator parametrises them along the lines. Forward: distance
    from x_b' to the point where the epipolar line F x_a' meets line_b; backward: from x_a' to
    where F^T x_b' meets line_a; the error is their mean (the paper's line homography error,
    Fig. 8, in pixels of the stored images). Inf where an epipolar line is parallel to its line.
    """
    F = np.asarray(F, dtype=np.float64)
    pa = project_to_line(line_a, np.asarray(pts_a, dtype=np.float64))
    pb = project_to_line(line_b, np.asarray(pts_b, dtype=np.float64))
    return 0.5 * (_transfer(F, line_b, pa, pb) + _transfer(F.T, line_a, pb, pa))


def outlier_rate(n_positives: int, n_matches: int) -> float:
    """1 - positives / matches: the pair's outlier rate r as the GT sees it (nan for 0 matches)."""
    return 1.0 - n_positives / n_matches if n_matches else math.nan


# A run without an F or a pose counts as this rotation / direction error (degrees).
POSE_FAILURE_DEG = 180.0


def pose_errors(
    F: np.ndarray | None,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    P_a: np.ndarray,
    P_b: np.ndarray,
    threshold: float,
) -> tuple[float, float]:
    """Rotation and translation-direction errors (degrees) of the pose from F vs GT cameras.

    The pose is :func:`sepfm_ros.geometry.pose.relative_pose` of F on its inliers (symmetric
    epipolar distance < ``threshold``) with the GT intrinsics; the reference is the relative
    pose of the 3x4 GT cameras P_a, P_b. ``POSE_FAILURE_DEG`` for both without F or pose.
    """
    from sepfm_ros.geometry.calibrated.pose import (
        direction_error_deg,
        pose_from_projections,
        relative_pose,
        rotation_error_deg,
    )

    if F is None:
        return POSE_FAILURE_DEG, POSE_FAILURE_DEG
    K_a, K_b, R_gt, t_gt = pose_from_projections(P_a, P_b)
    inl = inlier_mask(F, pts_a, pts_b, threshold)
    pose = relative_pose(F, pts_a, pts_b, K_a, K_b, inl, scale_px=threshold)
    if not pose.ok or not np.linalg.norm(t_gt) > 0:
        return POSE_FAILURE_DEG, POSE_FAILURE_DEG
    return rotation_error_deg(pose.R, R_gt), direction_error_deg(pose.t, t_gt)


def pose_summary(runs: list[dict]) -> tuple[int, float, float]:
    """(pairs, median rotation error, median translation-direction error) over runs with pose
    errors (records with ``rotation_error_deg`` not None); (0, nan, nan) without any."""
    rows = [r for r in runs if r.get("rotation_error_deg") is not None]
    if not rows:
        return 0, math.nan, math.nan
    return (
        len({r["pair"] for r in rows}),
        float(np.median([r["rotation_error_deg"] for r in rows])),
        float(np.median([r["translation_error_deg"] for r in rows])),
    )
