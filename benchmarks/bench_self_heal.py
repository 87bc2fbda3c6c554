"""Benchmark: a rig that heals. The corrected rotation of a knocked stereo camera from a window
of pairs (:mod:`sepfm_ros.geometry.calibrated.correction`), on KITTI and on synthetic rigs.

Rigs:

- ``kitti``: the shared KITTI stereo frames (kitti_seq2, rectified, 51 pairs; cameras.json).
  The truth of a knock is the injected rotation composed with the clean sequence's own reading
  (the mean of its pairs' fits), since KITTI's calibration is known to about 0.01-0.02 deg;
- ``synthetic``: :func:`sepfm_ros.synthetic.sequences.stereo_sequence` (a converged raw rig,
  480x360), exact truth.

From frame ``--change`` on, the right camera is turned about its own centre by 0.2, 0.5 and 1.0
deg about x (pitch), z (roll) and y (yaw): the right image is warped by K R K^-1 (KITTI) or
rendered by the turned camera (synthetic). Each pair goes through the node's pipeline and the
calibration check; windows of N = 10, 20 and 40 consecutive pairs after the change (disjoint)
give :func:`~sepfm_ros.geometry.calibrated.correction.estimate_correction`. Reported: the error
per axis against the truth, the interval's coverage and median half-width, the median vertical
disparity of ground-truth matches (the clean pair's matches within 1 px of the calibration,
moved by the knock's homography; synthetic: a grid of pixels cast onto the scene) and
OpenCV StereoSGBM's share of valid disparities after rectification with the stale, the
corrected (N = 20) and the true calibration, and corrections issued on the clean sequences
(by the estimator alone on every window, and gated by the monitor as the node runs it).

    python benchmarks/bench_self_heal.py [--quick] [--write-docs]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_docs  # noqa: E402
from bench_calibration_check import kitti_frames, kitti_rig  # noqa: E402

from sepfm_ros.geometry.calibrated.calibration_check import (  # noqa: E402
    ERROR,
    WARN,
    CalibrationMonitor,
    MonitorConfig,
    PairCheck,
    StereoCalibration,
    check_pair,
)
from sepfm_ros.geometry.calibrated.camera import CameraModel, camera_model  # noqa: E402
from sepfm_ros.geometry.calibrated.correction import (  # noqa: E402
    CorrectionConfig,
    CorrectionResult,
    CorrectionWindow,
    estimate_correction,
    pair_rotations,
)
from sepfm_ros.geometry.calibrated.stereo_rectify import corrected_models  # noqa: E402
from sepfm_ros.geometry.epipolar import symmetric_epipolar_distance  # noqa: E402
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig  # noqa: E402
from sepfm_ros.synthetic.scene import Camera, render  # noqa: E402
from sepfm_ros.synthetic.sequences import stereo_sequence, street_scene  # noqa: E402

AXES = {"pitch": 0, "roll": 2, "yaw": 1}
ANGLES = (0.2, 0.5, 1.0)
WINDOWS = (10, 20, 40)


@dataclass
class Rig:
    """A rig of the benchmark: its calibration, its camera_info models and its images."""

    name: str
    calib: StereoCalibration
    models: tuple[CameraModel, CameraModel]
    rectified: bool
    n_frames: int
    images: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]]  # (frame, dR) -> pair
    # exact matches (frame, dR) -> (pts_a, pts_b) in the estimator's pixels, None: from the
    # clean pair's matches
    exact: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None


@dataclass
class Pair:
    pts_a: np.ndarray
    pts_b: np.ndarray
    inliers: np.ndarray
    check: PairCheck
    refined_b: np.ndarray  # (N, 2) sub-pixel points of b the correction fits (NaN: failed)


def kitti(n_frames: int) -> Rig:
    calib = kitti_rig()
    frames = kitti_frames(n_frames)
    K = calib.model_b.K

    def images(k: int, dR: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        left, right = frames[k]
        if not np.allclose(dR, np.eye(3)):
            right = cv2.warpPerspective(right, K @ dR @ np.linalg.inv(K), right.shape[::-1])
        return left, right

    return Rig("kitti", calib, (calib.model_a, calib.model_b), True, n_frames, images)


def synthetic(n_frames: int, seed: int) -> Rig:
    frames = stereo_sequence(n_frames, speed_m=0.05, seed=seed)
    scene = street_scene(seed)
    cam_a, cam_b = frames[0].cameras
    R0 = cam_b.R @ cam_a.R.T
    T0 = cam_b.t - R0 @ cam_a.t
    size = cam_a.size
    R1, R2, P1, P2 = cv2.stereoRectify(
        cam_a.K, None, cam_b.K, None, size, R0, T0.reshape(3, 1), alpha=0
    )[:4]
    ma = camera_model(cam_a.K, [], "plumb_bob", R1, P1, *size)
    mb = camera_model(cam_b.K, [], "plumb_bob", R2, P2, *size)
    calib = StereoCalibration.from_models(ma, mb)

    def images(k: int, dR: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        left, right = frames[k].images
        if not np.allclose(dR, np.eye(3)):
            cb = frames[k].cameras[1]
            right = render(scene, Camera(cb.K, dR @ cb.R, dR @ cb.t, cb.size))
        return left, right

    def exact(k: int, dR: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ca, cb = frames[k].cameras
        return scene_matches(scene, ca, Camera(cb.K, dR @ cb.R, dR @ cb.t, cb.size))

    return Rig(f"synthetic (seed {seed})", calib, (ma, mb), False, n_frames, images, exact)


def scene_matches(scene, cam_a: Camera, cam_b: Camera, step: int = 8):
    """Exact matches: a grid of a's pixels cast onto the nearest plane, projected into b."""
    w, h = cam_a.size
    uu, vv = np.meshgrid(np.arange(step / 2, w, step), np.arange(step / 2, h, step))
    pa = np.stack([uu.ravel(), vv.ravel()], axis=1)
    rays = (cam_a.R.T @ np.linalg.inv(cam_a.K) @ np.c_[pa, np.ones(len(pa))].T).T
    C = cam_a.center
    depth = np.full(len(pa), np.inf)
    for plane in scene.planes:
        th, tw = plane.texture.shape[:2]
        n = np.cross(plane.u, plane.v)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (n @ (plane.origin - C)) / (rays @ n)
        st = (C + rays * lam[:, None] - plane.origin) @ np.linalg.pinv(np.c_[plane.u, plane.v]).T
        on = (lam > 0) & (st[:, 0] >= 0) & (st[:, 0] <= tw - 1) & (st[:, 1] >= 0)
        on &= (st[:, 1] <= th - 1) & (lam < depth)
        depth[on] = lam[on]
    hit = np.isfinite(depth)
    X = C + rays[hit] * depth[hit, None]
    xb = (cam_b.P @ np.c_[X, np.ones(len(X))].T).T
    pb = xb[:, :2] / xb[:, 2:]
    inside = np.all((pb >= 0) & (pb <= np.array(cam_b.size) - 1), axis=1) & (xb[:, 2] > 0)
    return pa[hit][inside], pb[inside]


def rotation(axis: str, deg: float) -> np.ndarray:
    rv = np.zeros(3)
    rv[AXES[axis]] = np.radians(deg)
    return np.asarray(Rotation.from_rotvec(rv).as_matrix())


def run_pairs(pipe: Pipeline, rig: Rig, dR: np.ndarray, change: int) -> list[Pair]:
    """Every pair of the rig through the pipeline and the check, camera b turned from change."""
    out = []
    for k in range(rig.n_frames):
        left, right = rig.images(k, dR if k >= change else np.eye(3))
        res = pipe.process(left, right, key_a=(rig.name, k), cameras=rig.models)
        est = res.estimate
        inl = est.inliers if est.F is not None else np.zeros(len(res.matches.pts_a), bool)
        pa, pb = res.matches.pts_a, res.matches.pts_b
        assert res.refined_b is not None  # the pipeline tracks them (subpixel_b), as the node
        out.append(Pair(pa, pb, inl, check_pair(rig.calib, pa, pb, inl), res.refined_b))
    return out


def window_of(pairs: list[Pair]) -> CorrectionWindow:
    w = CorrectionWindow(len(pairs))
    for p in pairs:
        if p.check.usable:
            w.add(p.pts_a, p.refined_b, p.check.fit)
    return w


def rectify_points(model: CameraModel, pts: np.ndarray) -> np.ndarray:
    D = model.D if model.D.size else None
    out = cv2.undistortPoints(pts.reshape(-1, 1, 2), model.K, D, R=model.R, P=model.P)
    return np.asarray(out.reshape(-1, 2))


def vertical_disparity(models: tuple[CameraModel, CameraModel], pa, pb) -> float:
    ra, rb = rectify_points(models[0], pa), rectify_points(models[1], pb)
    return float(np.median(np.abs(ra[:, 1] - rb[:, 1])))


def sgbm_share(models: tuple[CameraModel, CameraModel], left, right, n_disp: int) -> float:
    """Share of valid SGBM disparities (columns past n_disp) after rectifying with models."""
    rect = []
    for m, img in zip(models, (left, right), strict=True):
        D = m.D if m.D.size else None
        mx, my = cv2.initUndistortRectifyMap(m.K, D, m.R, m.P, m.size, cv2.CV_32FC1)
        rect.append(cv2.remap(img, mx, my, cv2.INTER_LINEAR))
    sgbm = cv2.StereoSGBM_create(0, n_disp, 5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=2)  # fmt: skip
    disp = sgbm.compute(rect[0], rect[1])[:, n_disp:]
    return float(np.mean(disp >= 0))


@dataclass
class Trial:
    rig: str
    axis: str
    deg: float
    n: int
    result: CorrectionResult
    truth_deg: np.ndarray  # (3,) truth of the correction (pitch x, yaw y, roll z)


def ground_truth_matches(clean: list[Pair], calib: StereoCalibration, k: int, H: np.ndarray):
    p = clean[k]
    d = symmetric_epipolar_distance(calib.F, p.pts_a, p.pts_b)
    sel = p.inliers & (d < 1.0)
    pb = cv2.perspectiveTransform(p.pts_b[sel].reshape(-1, 1, 2), H).reshape(-1, 2)
    return p.pts_a[sel], pb


def gated_corrections(
    pairs: list[Pair], calib: StereoCalibration, cfg: CorrectionConfig
) -> list[int]:
    """Pairs at which the node's flow (monitor WARN/ERROR -> estimate) issues a correction."""
    monitor = CalibrationMonitor(MonitorConfig())
    window = CorrectionWindow(cfg.window, cfg.min_matches)
    issued = []
    for k, p in enumerate(pairs):
        level = monitor.update(p.check).level
        if p.check.usable:
            window.add(p.pts_a, p.refined_b, p.check.fit)
        if level in (WARN, ERROR) and estimate_correction(calib, window, cfg).correction:
            issued.append(k)
    return issued


SHIFT_PX = 0.5  # the row shift of the right image in the error-sources table


def clean_window_spread(clean: list[Pair], rig: Rig, cfg: CorrectionConfig, n: int) -> np.ndarray:
    """(k, 3) deg: the readings of the disjoint clean windows of n pairs minus the whole
    sequence's: how much a window's reading depends on its scene."""
    pooled = np.degrees(pair_rotations(rig.calib, window_of(clean), cfg).mean(axis=0))
    reads = [
        np.degrees(pair_rotations(rig.calib, window_of(clean[s : s + n]), cfg).mean(axis=0))
        for s in range(0, rig.n_frames - n + 1, n)
    ]
    return np.array(reads).reshape(-1, 3) - pooled


def shift_response(pipe: Pipeline, rig: Rig, clean: list[Pair], cfg: CorrectionConfig):
    """Mean change (3,) deg of the pairs' readings when the right image is shifted down by
    SHIFT_PX (a pure row shift: pitch only, to first order) and, with exact matches (None
    without), the same shift of the matches alone."""
    shifted = Rig(rig.name, rig.calib, rig.models, rig.rectified, rig.n_frames,
                  lambda k, _dR: _shift_right(rig.images(k, np.eye(3)), SHIFT_PX))  # fmt: skip
    moved = run_pairs(pipe, shifted, np.eye(3), rig.n_frames)
    a = pair_rotations(rig.calib, window_of(clean), cfg)
    b = pair_rotations(rig.calib, window_of(moved), cfg)
    n = min(len(a), len(b))
    images = np.degrees((b[:n] - a[:n]).mean(axis=0))
    if rig.exact is None:
        return images, None
    exact = []
    for k in range(rig.n_frames):
        pa, pb = rig.exact(k, np.eye(3))
        w0, w1 = CorrectionWindow(1), CorrectionWindow(1)
        w0.add(pa, pb), w1.add(pa, pb + [0.0, SHIFT_PX])
        exact.append(pair_rotations(rig.calib, w1, cfg)[0] - pair_rotations(rig.calib, w0, cfg)[0])
    return images, np.degrees(np.mean(exact, axis=0))


def _shift_right(pair: tuple[np.ndarray, np.ndarray], dy: float):
    left, right = pair
    T = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, dy]])
    return left, cv2.warpAffine(right, T, right.shape[::-1], flags=cv2.INTER_LINEAR)


def evaluate_rig(pipe: Pipeline, rig: Rig, change: int, angles, axes, windows, cfg, log):
    """Trials, image figures and clean-rig figures of one rig."""
    n_img = windows[min(1, len(windows) - 1)]  # the window whose correction rectifies
    t0 = time.perf_counter()
    clean = run_pairs(pipe, rig, np.eye(3), rig.n_frames)
    omega_clean = pair_rotations(rig.calib, window_of(clean), cfg).mean(axis=0)
    log(f"{rig.name}: clean reading pitch {np.degrees(omega_clean[0]):+.3f}, yaw "
        f"{np.degrees(omega_clean[1]):+.3f}, roll {np.degrees(omega_clean[2]):+.3f} deg "
        f"({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    reference = omega_clean if rig.rectified else np.zeros(3)  # KITTI: its own reading
    trials: list[Trial] = []
    images: list[tuple[str, str, float, list[float], list[float]]] = []
    clean_issued = sum(
        estimate_correction(rig.calib, window_of(clean[s : s + n]), cfg).correction is not None
        for n in windows
        for s in range(0, rig.n_frames - n + 1, n)
    )
    clean_windows = sum(len(range(0, rig.n_frames - n + 1, n)) for n in windows)
    gated = gated_corrections(clean, rig.calib, cfg)
    spread = clean_window_spread(clean, rig, cfg, windows[min(1, len(windows) - 1)])
    response = shift_response(pipe, rig, clean, cfg)
    n_disp = 128 if rig.rectified else 64
    for axis in axes:
        for deg in angles:
            dR = rotation(axis, deg)
            pairs = run_pairs(pipe, rig, dR, change)
            R_truth = dR @ Rotation.from_rotvec(reference).as_matrix()
            truth = np.degrees(Rotation.from_matrix(R_truth).as_rotvec())
            for n in windows:
                for s in range(change, rig.n_frames - n + 1, n):
                    res = estimate_correction(rig.calib, window_of(pairs[s : s + n]), cfg)
                    trials.append(Trial(rig.name, axis, deg, n, res, truth))
            first = [t for t in trials if (t.axis, t.deg) == (axis, deg) and t.n == n_img]
            fix = first[0].result.correction if first else None
            true_models = corrected_models(
                *rig.models, R_truth @ rig.calib.R, R_truth @ rig.calib.t, rig.rectified
            )
            cases = {"stale": rig.models, "true": true_models}
            if fix is not None:
                cases["corrected"] = corrected_models(*rig.models, fix.R, fix.t, rig.rectified)
            K = rig.calib.model_b.K
            H = K @ dR @ np.linalg.inv(K)
            frames = list(range(change, min(change + n_img, rig.n_frames)))
            vd = {c: [] for c in cases}
            sg = {c: [] for c in cases}
            for k in frames:
                if rig.exact is not None:
                    pa, pb = rig.exact(k, dR)
                else:
                    pa, pb = ground_truth_matches(clean, rig.calib, k, H)
                for c, models in cases.items():
                    vd[c].append(vertical_disparity(models, pa, pb))
            for k in frames[:: max(1, len(frames) // 3)][:3]:
                left, right = rig.images(k, dR)
                for c, models in cases.items():
                    sg[c].append(sgbm_share(models, left, right, n_disp))
            order = ("stale", "corrected", "true")
            vd_row = [float(np.median(vd[c])) if c in vd else np.nan for c in order]
            sg_row = [float(np.mean(sg[c])) if c in sg else np.nan for c in order]
            images.append((rig.name, axis, deg, vd_row, sg_row))
            got = "none" if fix is None else f"{fix.axes_deg[AXES[axis]]:+.3f}"
            log(f"{rig.name}: {deg} deg {axis}: N={n_img} correction {got} (truth "
                f"{truth[AXES[axis]]:+.3f}); vertical disparity stale/corrected/true "
                + "/".join(f"{v:.2f}" for v in images[-1][3])
                + f" px ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    clean_figs = (clean_issued, clean_windows, len(gated), len(clean), spread, response)
    return trials, images, clean_figs, omega_clean


def _fmt(v: float, digits: int = 3) -> str:
    return "n/a" if not np.isfinite(v) else f"{v:.{digits}f}"


def accuracy_table(trials: list[Trial], windows) -> str:
    lines = ["| rig | knock | N | issued | error pitch (deg) | error roll (deg) | yaw read "
             "(truth) (deg) | covered pitch / roll | half-width pitch / roll / yaw (deg) |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    keys = sorted({(t.rig, t.axis, t.deg, t.n) for t in trials},
                  key=lambda k: (k[0], list(AXES).index(k[1]), k[2], k[3]))  # fmt: skip
    for rig, axis, deg, n in keys:
        ts = [t for t in trials if (t.rig, t.axis, t.deg, t.n) == (rig, axis, deg, n)]
        fixes = [(t.result.correction, t.truth_deg) for t in ts if t.result.correction]
        if not fixes:
            why = ts[0].result.reason.split(":")[0]
            lines.append(f"| {rig} | {deg} deg {axis} | {n} | 0/{len(ts)} ({why}) | | | | | |")
            continue
        err = np.array([f.axes_deg - tr for f, tr in fixes])
        half = np.array([f.interval_deg for f, _ in fixes])
        yaw = np.array([(f.yaw_estimate_deg, tr[1]) for f, tr in fixes])
        cov = np.abs(err) <= half
        lines.append(
            f"| {rig} | {deg} deg {axis} | {n} | {len(fixes)}/{len(ts)} | "
            f"{_worst(err[:, 0])} | {_worst(err[:, 2])} | {np.median(yaw[:, 0]):+.3f} "
            f"({np.median(yaw[:, 1]):+.3f}) | {cov[:, 0].sum()}/{len(fixes)} / "
            f"{cov[:, 2].sum()}/{len(fixes)} | {np.median(half[:, 0]):.3f} / "
            f"{np.median(half[:, 2]):.3f} / {np.median(half[:, 1]):.3f} |"
        )
    return "\n".join(lines)


def _worst(e: np.ndarray) -> str:
    """Median error, and the largest magnitude when several windows."""
    if len(e) == 1:
        return f"{e[0]:+.3f}"
    return f"{np.median(e):+.3f} (max {np.max(np.abs(e)):.3f})"


def summary(trials: list[Trial]) -> str:
    """Coverage and half-widths per axis over the issued corrections of pitch and roll knocks
    (yaw: the yaw read, applied or not)."""
    rows = ["| rig | axis | corrections | covered | coverage | median half-width (deg) |",
            "|---|---|---|---|---|---|"]  # fmt: skip
    for rig in sorted({t.rig for t in trials}):
        for axis in ("pitch", "roll", "yaw"):
            i = AXES[axis]
            fs = [(t.result.correction, t.truth_deg) for t in trials
                  if t.rig == rig and t.axis != "yaw" and t.result.correction]  # fmt: skip
            if not fs:
                continue
            value = [f.yaw_estimate_deg if axis == "yaw" else f.axes_deg[i] for f, _ in fs]
            err = np.array(value) - np.array([tr[i] for _, tr in fs])
            half = np.array([f.interval_deg[i] for f, _ in fs])
            cov = int(np.sum(np.abs(err) <= half))
            rows.append(f"| {rig} | {axis} | {len(fs)} | {cov} | {cov / len(fs):.0%} | "
                        f"{np.median(half):.3f} |")  # fmt: skip
    return "\n".join(rows)


def image_table(images) -> str:
    rows = [
        "| rig | knock | vertical disparity stale / corrected / true (px) | SGBM valid "
        "share stale / corrected / true | corrected vs true |",
        "|---|---|---|---|---|",
    ]
    for rig, axis, deg, vd, sg in images:
        rel = sg[1] / sg[2] - 1 if np.isfinite(sg[1]) else np.nan
        rows.append(f"| {rig} | {deg} deg {axis} | {' / '.join(_fmt(v, 2) for v in vd)} | "
                    f"{' / '.join(_fmt(v, 3) for v in sg)} | "
                    f"{'n/a' if not np.isfinite(rel) else f'{rel:+.1%}'} |")  # fmt: skip
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--change", type=int, default=10, help="first knocked frame (KITTI)")
    ap.add_argument("--synthetic-frames", type=int, default=44)
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1], help="synthetic rigs")
    ap.add_argument("--quick", action="store_true",
                    help="smoke test: 22 KITTI frames, one synthetic rig of 14 frames, 0.5 deg "
                    "pitch and roll, N = 10")  # fmt: skip
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--doc", type=Path, default=bench_docs.BENCH_DOC)
    a = ap.parse_args(argv)
    cfg = CorrectionConfig()
    angles, axes, windows = ANGLES, tuple(AXES), WINDOWS
    kitti_frames, change, syn_frames, seeds = 51, a.change, a.synthetic_frames, a.seeds
    if a.quick:
        angles, axes, windows = (0.5,), ("pitch", "roll"), (10,)
        kitti_frames, change, syn_frames, seeds = 22, 2, 14, seeds[:1]
    t0 = time.perf_counter()
    pipe = Pipeline(PipelineConfig(), cache_size=2 * max(kitti_frames, syn_frames), subpixel_b=True)

    def log(text: str) -> None:
        print(text, flush=True)

    rigs = [(kitti(kitti_frames), change)]
    rigs += [(synthetic(syn_frames, s), 4 if not a.quick else 2) for s in seeds]
    trials: list[Trial] = []
    images = []
    clean_rows = []
    for rig, ch in rigs:
        t, im, cl, om = evaluate_rig(pipe, rig, ch, angles, axes, windows, cfg, log)
        trials += t
        images += im
        clean_rows.append((rig.name, *cl, np.degrees(om)))
    elapsed = time.perf_counter() - t0
    n_img = windows[min(1, len(windows) - 1)]
    clean = ["| rig | clean reading pitch / yaw / roll (deg) | corrections on clean windows "
             "(estimator alone) | pairs with a correction (monitor-gated, as the node) |",
             "|---|---|---|---|"]  # fmt: skip
    sources = [f"| rig | pitch / roll read on clean windows of N = {n_img} minus the whole "
               "sequence's: sd (largest) (deg) | right image shifted "
               f"{SHIFT_PX} px down: change pitch / yaw / roll (deg) | exact matches shifted "
               f"{SHIFT_PX} px: change pitch / yaw / roll (deg) |",
               "|---|---|---|---|"]  # fmt: skip
    for name, issued, n_windows, gated, n_pairs, dev, (img, exact), om in clean_rows:
        clean.append(f"| {name} | {om[0]:+.3f} / {om[1]:+.3f} / {om[2]:+.3f} | "
                     f"{issued}/{n_windows} | {gated}/{n_pairs} |")  # fmt: skip
        spread = " / ".join(
            f"{dev[:, i].std(ddof=1):.3f} ({np.max(np.abs(dev[:, i])):.3f})" if len(dev) > 1
            else "n/a" for i in (0, 2)
        )  # fmt: skip
        ex = "n/a" if exact is None else " / ".join(f"{v:+.3f}" for v in exact)
        sources.append(f"| {name} | {spread} | {' / '.join(f'{v:+.3f}' for v in img)} | "
                       f"{ex} |")  # fmt: skip
    body = "\n\n".join([
        f"Knock from frame {change} (KITTI) / 4 (synthetic), windows of N = "
        f"{', '.join(map(str, sorted(set(windows))))} consecutive pairs after it (disjoint); "
        f"correction defaults ({cfg.min_pairs} pairs at least, band {cfg.band_px} px, "
        f"systematic floor {cfg.systematic_mrad} mrad, no correction under "
        f"{cfg.min_correction_deg} deg, yaw applied when its interval is under "
        f"{cfg.yaw_max_interval_deg} deg). Errors against the truth (KITTI: the knock composed "
        "with the clean sequence's reading); a window's yaw is read but kept at the "
        "calibration unless determined.",
        "**Corrected rotation per window**\n\n" + accuracy_table(trials, windows),
        "**Intervals of the corrections of pitch and roll knocks** (95 %; yaw knocks: the "
        "rows above)\n\n" + summary(trials),
        f"**Rectified with the stale, the corrected (N = {n_img}) and the true "
        "calibration** (median over the window's frames of the median vertical disparity of "
        "ground-truth matches; SGBM on 3 frames)\n\n" + image_table(images),
        "**Clean rigs**\n\n" + "\n".join(clean),
        "**Where the remaining roll error comes from** (a clean synthetic rig's roll reading "
        "is its error: its truth is 0; a row shift moves pitch alone, to first order)\n\n"
        + "\n".join(sources),
        f"Run time {elapsed:.0f} s.",
    ])  # fmt: skip
    print(body)
    if a.write_docs:
        command = bench_docs.command_line("bench_self_heal.py", argv)
        title = "A rig that heals: corrected stereo rotation from a window of pairs"
        path = bench_docs.write_section(
            "bench_self_heal", bench_docs.section("bench_self_heal", title, command, body), a.doc
        )
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
