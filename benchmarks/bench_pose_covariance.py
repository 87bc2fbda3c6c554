"""Benchmark: does the relative pose's covariance bound its error against ground truth?

Pairs: kitti_seq2 left frames 1, 2 and 4 apart, consecutive templeRing views
(../shared/data/cameras.json holds every camera: K, R, t of each image), and the small-baseline
pairs of three Strecha scenes (../shared/data_lines: fountain-P11, Herz-Jesu-P8, entry-P10, whose
cameras were registered to a laser scan, the most accurate ground truth of the shared data).
Matches: the node's pipeline, default config; pose:
:func:`sepfm_ros.geometry.pose.relative_pose` with the GT intrinsics and its covariance
(:mod:`sepfm_ros.geometry.calibrated.pose_covariance`).

Per pair: the rotation error (the rotation vector delta with R_est = exp(delta) R_gt) and the
translation-direction error (the tangent vector eta from t_est to t_gt), and the 95% bound the
covariance sets on each along the error's own direction: the radius of the ellipsoid
``x^T C^-1 x = chi2_k(0.95)`` (k = 3 for the rotation, 2 for the direction). The error is
covered when it lies within that ellipsoid. Printed per set and in all: the share of pairs
covered (target >= 90%) and the median bound over the median error (target <= 3).

    python benchmarks/bench_pose_covariance.py [--write-docs]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_docs  # noqa: E402
from bench_pose import pair_sets  # noqa: E402  (the same pairs as the pose benchmark)

from sepfm_ros.geometry.calibrated.pose import (  # noqa: E402
    pose_from_projections,
    pose_inliers,
    relative_pose,
)
from sepfm_ros.geometry.calibrated.pose_covariance import (  # noqa: E402
    cut_variance_factor,
    direction_error,
    rotation_error,
    sampson_residuals,
)
from sepfm_ros.geometry.epipolar import homogeneous  # noqa: E402
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig  # noqa: E402

DATA = bench_docs.REPO.parent / "shared" / "data"
DATA_LINES = bench_docs.REPO.parent / "shared" / "data_lines"
STRECHA_SCENES = ("fountain-P11", "Herz-Jesu-P8", "entry-P10")
BOOTSTRAP_ROUNDS = 30
CHI2_ROT, CHI2_DIR = chi2.ppf(0.95, 3), chi2.ppf(0.95, 2)
TARGET_COVERED, TARGET_RATIO = 0.90, 3.0


def strecha_pairs() -> list[tuple[str, str]]:
    """The small-baseline pairs (parallax under 15 degrees) of the three Strecha scenes."""
    pairs = json.loads((DATA_LINES / "pairs.json").read_text())
    return [
        (p["img_a"], p["img_b"])
        for p in pairs
        if p["baseline"] == "small" and p["scene"] in STRECHA_SCENES
    ]


def evaluate_pair(pipe: Pipeline, cams: dict, a: str, b: str, data: Path = DATA) -> dict | None:
    """Errors and bounds (deg) of one pair, None when it gives no pose with a covariance."""
    img_a = cv2.imread(str(data / a), cv2.IMREAD_GRAYSCALE)
    img_b = cv2.imread(str(data / b), cv2.IMREAD_GRAYSCALE)
    K_a, K_b, R_gt, t_gt = pose_from_projections(np.array(cams[a]), np.array(cams[b]))
    res = pipe.process(img_a, img_b)
    if res.estimate.F is None:
        return None
    pa, pb = res.matches.pts_a, res.matches.pts_b
    pose = relative_pose(res.estimate.F, pa, pb, K_a, K_b, res.estimate.inliers)
    c = pose.covariance
    if not pose.ok or c is None:
        return None
    # how far the ground truth is from the matches: the rise of the inliers' squared Sampson
    # distances from the estimate to the GT pose, in units of the covariance's variance; with
    # a right covariance and an exact GT it follows chi-square with 5 dof (median 4.4)
    sel = pose_inliers(pose.R, pose.t, pa, pb, K_a, K_b, 1.0)
    Ki = (np.linalg.inv(K_a), np.linalg.inv(K_b))
    xa, xb = homogeneous(pa[sel]), homogeneous(pb[sel])
    r_est = sampson_residuals(pose.R, pose.t, xa, xb, *Ki)
    r_gt = sampson_residuals(R_gt, t_gt / np.linalg.norm(t_gt), xa, xb, *Ki)
    variance = c.sigma_px**2 * cut_variance_factor(1.0 / c.sigma_px)
    halves = split_half(res.estimate.F, pa[sel], pb[sel], K_a, K_b)
    boot = bootstrap_ratio(res.estimate.F, pose, pa[sel], pb[sel], K_a, K_b)
    d = rotation_error(pose.R, R_gt)
    e = direction_error(pose.t, t_gt, c.basis)
    return {
        "rot_err": float(np.degrees(np.linalg.norm(d))),
        "rot_bound": c.rotation_bound_deg(d, CHI2_ROT),
        "dir_err": float(np.degrees(np.linalg.norm(e))),
        "dir_bound": c.direction_bound_deg(e, CHI2_DIR),
        "sigma_px": c.sigma_px,
        "halves": halves,
        "bootstrap": boot,
        "gt_rise": float((r_gt @ r_gt - r_est @ r_est) / variance),
        "n": c.n_points,
    }


def split_half(F, pa, pb, K_a, K_b) -> float:
    """A check without ground truth: the pose's inliers split at the median column of image a,
    each half's rotation and its covariance; the squared Mahalanobis distance between the two
    rotations under the sum of their covariances (chi-square with 3 dof, median 2.4, when the
    covariance is right and the halves' errors independent). NaN when a half has no pose."""
    left = pa[:, 0] < np.median(pa[:, 0])
    poses = [relative_pose(F, pa[h], pb[h], K_a, K_b, None, reselect=0) for h in (left, ~left)]
    if not all(p.ok and p.covariance is not None for p in poses):
        return float("nan")
    diff = rotation_error(poses[0].R, poses[1].R)
    C = poses[0].covariance.cov[:3, :3] + poses[1].covariance.cov[:3, :3]
    return float(diff @ np.linalg.solve(C, diff))


def bootstrap_ratio(F, pose, pa, pb, K_a, K_b) -> float:
    """A second check without GT: the rotation's spread over ``BOOTSTRAP_ROUNDS`` resamplings of
    the inliers (with replacement, each refined from F) over the covariance's, as the ratio of
    the square roots of the traces; about 1 when the covariance is the matches' own scatter,
    whatever its distribution. NaN when too few resamplings give a pose."""
    rng = np.random.default_rng(0)
    deltas = []
    for _ in range(BOOTSTRAP_ROUNDS):
        s = rng.integers(0, len(pa), len(pa))
        p = relative_pose(F, pa[s], pb[s], K_a, K_b, None, reselect=0)
        if p.ok:
            deltas.append(rotation_error(p.R, pose.R))
    if len(deltas) < BOOTSTRAP_ROUNDS // 2:
        return float("nan")
    spread = np.trace(np.cov(np.array(deltas).T))
    return float(np.sqrt(spread / np.trace(pose.covariance.cov[:3, :3])))


def summary(rows: list[dict], kind: str) -> tuple[float, float]:
    """(share covered, median bound / median error) of ``kind`` ("rot" or "dir")."""
    err = np.array([r[f"{kind}_err"] for r in rows])
    bound = np.array([r[f"{kind}_bound"] for r in rows])
    return float(np.mean(err <= bound)), float(np.median(bound) / np.median(err))


def table(results: dict[str, list[dict]], failed: dict[str, int]) -> list[str]:
    lines = [
        "| pairs | with a covariance | median inliers | median sigma (px) | GT rise (median, "
        "chi2_5: 4.4) | halves (median, chi2_3: 2.4) | bootstrap / covariance (median) | "
        "rotation: median "
        "error / 95% bound (deg) | covered | bound / error | direction: median error / 95% "
        "bound (deg) | covered | bound / error |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    every = [r for rows in results.values() for r in rows]
    for name, rows in [*results.items(), ("all", every)]:
        n_fail = sum(failed.values()) if name == "all" else failed[name]
        cr, rr = summary(rows, "rot")
        cd, rd = summary(rows, "dir")
        med = {k: np.nanmedian([r[k] for r in rows]) for k in rows[0]}
        lines.append(
            f"| {name} | {len(rows)} of {len(rows) + n_fail} | {med['n']:.0f} | "
            f"{med['sigma_px']:.2f} | {med['gt_rise']:.0f} | {med['halves']:.1f} | "
            f"{med['bootstrap']:.2f} | "
            f"{med['rot_err']:.3f} / {med['rot_bound']:.3f} | "
            f"{cr:.0%} | {rr:.2f} | {med['dir_err']:.2f} / {med['dir_bound']:.2f} | {cd:.0%} | "
            f"{rd:.2f} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--doc", type=Path, default=bench_docs.BENCH_DOC)
    ap.add_argument("--write-docs", action="store_true", help="rewrite its docs section")
    args = ap.parse_args(argv)
    cams = json.loads((DATA / "cameras.json").read_text())
    pipe = Pipeline(PipelineConfig())
    t0 = time.perf_counter()
    results: dict[str, list[dict]] = {}
    failed: dict[str, int] = {}
    lines_cams = json.loads((DATA_LINES / "cameras.json").read_text())
    sets = {name: (pairs, cams, DATA) for name, pairs in pair_sets(cams).items()}
    sets["Strecha, small baseline"] = (strecha_pairs(), lines_cams, DATA_LINES)
    for name, (pairs, set_cams, data) in sets.items():
        print(f"{name}: {len(pairs)} pairs", file=sys.stderr, flush=True)
        rows = [evaluate_pair(pipe, set_cams, a, b, data) for a, b in pairs]
        results[name] = [r for r in rows if r is not None]
        failed[name] = sum(r is None for r in rows)
    every = [r for rows in results.values() for r in rows]
    (cr, rr), (cd, rd) = summary(every, "rot"), summary(every, "dir")
    ok = min(cr, cd) >= TARGET_COVERED and max(rr, rd) <= TARGET_RATIO
    text = "\n".join(
        [
            "Node pipeline matches (default config), GT intrinsics and poses from cameras.json; "
            "the pose and its covariance as the node computes them. Per pair, the 95% bound is "
            "the radius of the covariance's 95% ellipsoid (chi-square, 3 dof for the rotation, 2 "
            "for the direction) along the error; 'covered': share of pairs whose error is "
            "within it (target >= 90%); 'bound / error': median bound over median error "
            "(target <= 3). 'GT rise': how much worse the GT pose fits the pair's inliers than "
            "the estimate, in units of the covariance's variance (sum of squared Sampson "
            "distances under GT minus under the estimate, over c sigma^2); chi-square with 5 "
            "dof (median 4.4) when the covariance is right and the GT exact. Above that, the "
            "matches themselves reject the GT pose: the error then includes the GT's own. "
            "'halves': a check without GT, the squared Mahalanobis distance between the "
            "rotations of the inliers' left and right halves (image a), under the sum of their "
            "covariances; chi-square with 3 dof (median 2.4) when the covariance is right. "
            "'bootstrap / covariance': the rotation's spread over 30 resamplings of the inliers "
            "over the covariance's (about 1 when the covariance is the matches' own scatter).",
            "",
            *table(results, failed),
            "",
            f"All pairs: rotation covered {cr:.0%}, bound / error {rr:.2f}; direction covered "
            f"{cd:.0%}, bound / error {rd:.2f}: targets {'met' if ok else 'NOT met'}. Run "
            f"time {time.perf_counter() - t0:.0f} s.",
        ]
    )
    print(text)
    if args.write_docs:
        command = bench_docs.command_line("bench_pose_covariance.py", argv)
        section = bench_docs.section(
            "bench_pose_covariance", "Relative pose covariance against ground truth", command, text
        )
        path = bench_docs.write_section("bench_pose_covariance", section, args.doc)
        print(f"wrote {path}", file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
