"""Benchmark: relative pose from the node's matches against the ground-truth cameras.

Pairs: kitti_seq2 left frames 1, 2 and 4 apart, and consecutive templeRing views
(../shared/data/cameras.json holds every camera). Matches: the node's pipeline, default config
(ORB 1000, ratio 0.8). Methods on the same matches, with the GT intrinsics:

- ``ours``: F by our estimator (the pipeline's default method, 1 px), then
  :func:`sepfm_ros.geometry.pose.relative_pose` (E = K_b^T F K_a, cheirality, Sampson
  refinement of R, t on F's inliers, then twice re-selecting the inliers among all matches
  under the pose and refitting);
- ``ours, refined on F's inliers only``: without the re-selection;
- ``ours, no refinement``: the bare decomposition of E;
- ``ours + E refit``: our inliers, E re-estimated on them by OpenCV (LMedS), ``recoverPose``;
- ``OpenCV USAC_MAGSAC`` / ``OpenCV RANSAC``: ``findEssentialMat`` on all matches (1 px,
  confidence 0.99) + ``recoverPose``.

Printed per set and method: median rotation error (deg) and median translation-direction error
(deg), and the share of pairs with rotation error under 1 deg.

    python benchmarks/bench_pose.py [--out docs/calibration_pose.md]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from sepfm_ros.geometry.calibrated.pose import (
    direction_error_deg,
    normalized_points,
    pose_from_projections,
    relative_pose,
    rotation_error_deg,
)
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
METHODS = (
    "ours",
    "ours, refined on F's inliers only",
    "ours, no refinement",
    "ours + E refit",
    "OpenCV USAC_MAGSAC",
    "OpenCV RANSAC",
)


def pair_sets(cams: dict) -> dict[str, list[tuple[str, str]]]:
    left = sorted(k for k in cams if k.startswith("kitti_seq2/left/"))
    temple = sorted(k for k in cams if k.startswith("templeRing/"))
    sets = {
        f"KITTI, {g} apart": [(left[i], left[i + g]) for i in range(len(left) - g)]
        for g in (1, 2, 4)
    }
    sets["templeRing, consecutive"] = [(temple[i], temple[i + 1]) for i in range(len(temple) - 1)]
    return sets


def opencv_pose(na, nb, f, method, mask=None):
    """findEssentialMat (normalised points, 1 px threshold) + recoverPose; None on failure."""
    pa, pb = (na, nb) if mask is None else (na[mask], nb[mask])
    if len(pa) < 5:
        return None
    if method == cv2.LMEDS:
        E, inl = cv2.findEssentialMat(pa, pb, np.eye(3), method=cv2.LMEDS, prob=0.99)
    else:
        E, inl = cv2.findEssentialMat(
            pa, pb, np.eye(3), method=method, prob=0.99, threshold=1.0 / f
        )
    if E is None or E.shape != (3, 3):
        E = None if E is None else E[:3]
    if E is None:
        return None
    _, R, t, _ = cv2.recoverPose(E, pa, pb, np.eye(3), mask=inl)
    return R, t.ravel()


def evaluate_pair(pipe, cams, a, b):
    img_a = cv2.imread(str(DATA / a), cv2.IMREAD_GRAYSCALE)
    img_b = cv2.imread(str(DATA / b), cv2.IMREAD_GRAYSCALE)
    K_a, K_b, R_gt, t_gt = pose_from_projections(np.array(cams[a]), np.array(cams[b]))
    res = pipe.process(img_a, img_b)
    pa, pb = res.matches.pts_a, res.matches.pts_b
    na, nb = normalized_points(K_a, pa), normalized_points(K_b, pb)
    f = float(np.mean([K_a[0, 0], K_a[1, 1], K_b[0, 0], K_b[1, 1]]))
    poses = {}
    if res.estimate.F is not None:
        inl = res.estimate.inliers
        variants = (
            ("ours", True, 2),
            ("ours, refined on F's inliers only", True, 0),
            ("ours, no refinement", False, 0),
        )
        for name, refine, reselect in variants:
            pose = relative_pose(
                res.estimate.F, pa, pb, K_a, K_b, inl, refine=refine, reselect=reselect
            )
            poses[name] = (pose.R, pose.t) if pose.ok else None
        poses["ours + E refit"] = opencv_pose(na, nb, f, cv2.LMEDS, inl)
    for name, flag in (("OpenCV USAC_MAGSAC", cv2.USAC_MAGSAC), ("OpenCV RANSAC", cv2.RANSAC)):
        cv2.setRNGSeed(0)
        poses[name] = opencv_pose(na, nb, f, flag)
    out = {}
    for name in METHODS:
        pose = poses.get(name)
        # a method without a pose counts as a 180 degree error (failure)
        out[name] = (
            (180.0, 180.0)
            if pose is None
            else (rotation_error_deg(pose[0], R_gt), direction_error_deg(pose[1], t_gt))
        )
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=REPO / "docs" / "calibration_pose.md")
    a = p.parse_args(argv)
    cams = json.loads((DATA / "cameras.json").read_text())
    pipe = Pipeline(PipelineConfig())
    t0 = time.perf_counter()
    text = [
        "# Relative pose against ground-truth cameras",
        "",
        "`python benchmarks/bench_pose.py`",
        "",
        "Node pipeline matches (ORB 1000, ratio 0.8), GT intrinsics from cameras.json. Median "
        "rotation error and translation-direction error (deg) against the GT cameras; "
        "'R < 1 deg': share of pairs. A method without a pose counts as 180 deg.",
        "",
        "| pairs | method | median rotation error (deg) | median translation-direction "
        "error (deg) | R < 1 deg |",
        "|---|---|---|---|---|",
    ]
    for set_name, pairs in pair_sets(cams).items():
        errs = {m: [] for m in METHODS}
        for a_img, b_img in pairs:
            for m, e in evaluate_pair(pipe, cams, a_img, b_img).items():
                errs[m].append(e)
        for m in METHODS:
            e = np.array(errs[m])
            line = (
                f"| {set_name} ({len(pairs)}) | {m} | {np.median(e[:, 0]):.3f} | "
                f"{np.median(e[:, 1]):.2f} | {np.mean(e[:, 0] < 1.0):.0%} |"
            )
            text.append(line)
            print(line, flush=True)
    text += ["", f"Run time {time.perf_counter() - t0:.0f} s."]
    out = "\n".join(text)
    print(out)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(out + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
