"""Benchmark: the stereo calibration check on the shared KITTI stereo frames.

The rig's calibration comes from ../shared/data/cameras.json (KITTI's rectified cameras). The
51 stereo pairs of kitti_seq2 are checked in order by the node's pipeline (default config) and
:class:`~sepfm_ros.geometry.calibrated.calibration_check.CalibrationMonitor` (default
parameters). From pair
``--change`` on, the right image is warped by the homography K R K^-1 of a rotation of the right
camera by 0.1, 0.2, 0.5 or 1 degree about its x or its z axis. Reported per case: detection delay
(pairs from the change until the decision is WARN or worse), false alarms (WARN or worse before
the change, and over the whole clean sequence), the median per-pair figures after the change.

    python benchmarks/bench_calibration_check.py [--change 20] [--out docs/calibration_check.md]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from sepfm_ros.geometry.calibrated.calibration_check import (
    OK,
    STALE,
    CalibrationMonitor,
    MonitorConfig,
    StereoCalibration,
    check_pair,
)
from sepfm_ros.geometry.calibrated.camera import camera_model
from sepfm_ros.geometry.calibrated.pose import pose_from_projections
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
FRAMES = 51
ANGLES = (0.1, 0.2, 0.5, 1.0)


def kitti_rig() -> StereoCalibration:
    """The KITTI rig from cameras.json (frame 0's P matrices, rig frame = left camera)."""
    cams = json.loads((DATA / "cameras.json").read_text())
    K_a, K_b, _, t = pose_from_projections(
        np.array(cams["kitti_seq2/left/000000.png"]), np.array(cams["kitti_seq2/right/000000.png"])
    )
    ma = camera_model(K_a, [], "", np.eye(3), K_a @ np.eye(3, 4), 1241, 376)
    mb = camera_model(K_b, [], "", np.eye(3), K_b @ np.c_[np.eye(3), t], 1241, 376)
    return StereoCalibration.from_models(ma, mb, rectified=True)


def kitti_frames(n_frames: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The first ``n_frames`` (left, right) grey frames of kitti_seq2."""
    return [
        tuple(
            cv2.imread(str(DATA / f"kitti_seq2/{s}/{k:06d}.png"), cv2.IMREAD_GRAYSCALE)
            for s in ("left", "right")
        )
        for k in range(n_frames)
    ]


def run_case(pipe, calib, images, axis, deg, change, config):
    """Levels and checks of one sequence; the right image rotated from pair ``change`` on."""
    rv = np.zeros(3)
    if axis is not None:
        rv["xyz".index(axis)] = np.radians(deg)
    K = calib.model_b.K
    H = K @ cv2.Rodrigues(rv)[0] @ np.linalg.inv(K)
    monitor = CalibrationMonitor(config)
    levels, checks = [], []
    for k, (left, right) in enumerate(images):
        if axis is not None and k >= change:
            right = cv2.warpPerspective(right, H, (right.shape[1], right.shape[0]))
        res = pipe.process(left, right, key_a=("l", k), cameras=(calib.model_a, calib.model_b))
        c = check_pair(calib, res.matches.pts_a, res.matches.pts_b, res.estimate.inliers)
        levels.append(monitor.update(c).level)
        checks.append(c)
    return levels, checks


def alarms(levels) -> int:
    return sum(1 for lv in levels if lv not in (OK, STALE))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--change", type=int, default=20, help="first decalibrated pair")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "calibration_check.md")
    a = p.parse_args(argv)
    config = MonitorConfig()
    calib = kitti_rig()
    images = kitti_frames(FRAMES)
    pipe = Pipeline(PipelineConfig(), cache_size=FRAMES)
    t0 = time.perf_counter()
    clean_levels, clean_checks = run_case(pipe, calib, images, None, 0.0, a.change, config)
    rows = []
    for axis in ("x", "z"):
        for deg in ANGLES:
            levels, checks = run_case(pipe, calib, images, axis, deg, a.change, config)
            after = levels[a.change :]
            bad = [i for i, lv in enumerate(after) if lv not in (OK, STALE)]
            delay = bad[0] + 1 if bad else None
            post = [c for c in checks[a.change :] if c.usable]
            rows.append(
                (
                    axis,
                    deg,
                    delay,
                    alarms(levels[: a.change]),
                    float(np.median([c.epipolar_median_px for c in post])),
                    float(np.median([c.rotation_error_deg for c in post])),
                    max(levels[a.change :]),
                )
            )
            print(f"{axis} {deg} deg: delay {delay} pairs, levels after change {after}", flush=True)
    elapsed = time.perf_counter() - t0
    clean_rot = [c.rotation_error_deg for c in clean_checks if c.usable]
    clean_epi = [c.epipolar_median_px for c in clean_checks if c.usable]
    names = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
    text = [
        "# Stereo calibration check on KITTI",
        "",
        f"`python benchmarks/bench_calibration_check.py --change {a.change}`",
        "",
        f"{FRAMES} stereo pairs of kitti_seq2 in order, node pipeline (ORB 1000, ratio 0.8, "
        f"{PipelineConfig().method}, 1 px), monitor defaults "
        f"(window {config.window}, min_pairs {config.min_pairs}, min_inliers "
        f"{config.min_inliers}, WARN at {config.warn_epipolar_px} px / "
        f"{config.warn_rotation_deg} deg, ERROR at {config.error_epipolar_px} px / "
        f"{config.error_rotation_deg} deg). The right image is warped by K R K^-1 from pair "
        f"{a.change + 1} on. Delay = pairs from the change until WARN or worse.",
        "",
        "| rotation | detection delay (pairs) | false alarms before change | worst level "
        "after | median epipolar error after (px) | median rotation error after (deg) |",
        "|---|---|---|---|---|---|",
    ]
    for axis, deg, delay, fa, epi, rot, worst in rows:
        text.append(
            f"| {deg} deg about {axis} | {delay if delay is not None else 'not flagged'} | "
            f"{fa} | {names[worst]} | {epi:.2f} | {rot:.3f} |"
        )
    text += [
        "",
        f"Clean sequence ({FRAMES} pairs): {alarms(clean_levels)} false alarms; per-pair "
        f"epipolar median {np.median(clean_epi):.2f} px (max {np.max(clean_epi):.2f}), "
        f"rotation error median {np.median(clean_rot):.3f} deg (max {np.max(clean_rot):.3f}).",
        f"Run time {elapsed:.0f} s ({9 * FRAMES} pairs).",
    ]
    out = "\n".join(text)
    print(out)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(out + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
