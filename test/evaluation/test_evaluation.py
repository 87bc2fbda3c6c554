"""`sepfm_ros eval` end to end: manifest -> matches cache -> every method -> report and figures.

A small manifest mixes real shared pairs, a synthetic pair with exact ground truth (random
cameras, 3D points and 3D line segments, given as matches) and broken entries that must show up
as per-pair errors in the report, not crash the run.
"""

from __future__ import annotations

import csv
import json
import math
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from optional_tools import detector_param

from sepfm_ros.evaluation import cli
from sepfm_ros.evaluation.manifest import load_manifest
from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings, cache_key, file_hash
from sepfm_ros.evaluation.methods import REGISTRY, Method, available_methods
from sepfm_ros.evaluation.run import EvalConfig, _safe_run
from sepfm_ros.geometry import fundamental_from_cameras, symmetric_epipolar_distance

SIZE = (640, 480)


def _rotation(rvec) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    return R


def synthetic_entry(seed: int = 0, outlier_fraction: float = 0.3) -> dict:
    """A points entry with exact GT F: random cameras, 3D points plus points on 3D segments
    (collinear in both images, for the separable methods' line pair), 0.1 px noise, outliers."""
    rng = np.random.default_rng(seed)
    K = np.array([[520.0, 0.0, 320.0], [0.0, 520.0, 240.0], [0.0, 0.0, 1.0]])
    P_a = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    R_b = _rotation(rng.normal(0.0, 0.04, 3))
    t_b = np.array([-0.8, 0.1, 0.1]) + rng.normal(0.0, 0.05, 3)
    P_b = K @ np.hstack([R_b, t_b[:, None]])
    X = rng.uniform([-2.5, -1.8, 5.0], [2.5, 1.8, 9.0], size=(180, 3))
    for _ in range(4):  # 3D segments, 10 points each
        e0, e1 = rng.uniform([-2.0, -1.5, 5.0], [2.0, 1.5, 8.0], size=(2, 3))
        s = rng.uniform(0.0, 1.0, size=(10, 1))
        X = np.vstack([X, e0 + s * (e1 - e0)])
    Xh = np.hstack([X, np.ones((len(X), 1))])

    def project(P):
        x = Xh @ P.T
        return x[:, :2] / x[:, 2:]

    pa, pb = project(P_a), project(P_b)
    inside = np.all((pa >= 0) & (pa < SIZE) & (pb >= 0) & (pb < SIZE), axis=1)
    pa, pb = pa[inside], pb[inside]
    pa = pa + rng.normal(0.0, 0.1, pa.shape)
    pb = pb + rng.normal(0.0, 0.1, pb.shape)
    n_out = int(outlier_fraction * len(pa))
    idx = rng.choice(len(pa), n_out, replace=False)
    pb[idx] = rng.uniform([0, 0], SIZE, size=(n_out, 2))
    order = rng.permutation(len(pa))
    return {
        "scene": "synthetic",
        "name": f"synthetic/{seed}",
        "pts_a": pa[order].tolist(),
        "pts_b": pb[order].tolist(),
        "size_a": list(SIZE),
        "size_b": list(SIZE),
        "F": fundamental_from_cameras(P_a, P_b).tolist(),
    }


def broken_entries(tmp_path: Path) -> list[dict]:
    """Entries that each must become one per-pair error with a clear reason."""
    blank = np.full((240, 320), 128, np.uint8)
    cv2.imwrite(str(tmp_path / "blank_a.png"), blank)
    cv2.imwrite(str(tmp_path / "blank_b.png"), blank)
    (tmp_path / "corrupt.png").write_bytes(b"not an image at all")
    good_F = [[0, 0, 0], [0, 0, -1], [0, 1, 0]]
    few = np.random.default_rng(1).uniform(0, 300, (5, 2)).tolist()
    return [
        {"scene": "bad", "name": "missing-image", "img_a": "nowhere/a.png",
         "img_b": "blank_b.png", "F": good_F},
        {"scene": "bad", "name": "malformed-F", "img_a": "blank_a.png", "img_b": "blank_b.png",
         "F": [[1, 2, 3], [4, 5, 6]]},
        {"scene": "bad", "name": "five-matches", "pts_a": few, "pts_b": few,
         "size_a": [320, 240], "F": good_F},
        {"scene": "bad", "name": "no-texture", "img_a": "blank_a.png", "img_b": "blank_b.png",
         "F": good_F},
        {"scene": "bad", "name": "corrupt-image", "img_a": "corrupt.png",
         "img_b": "blank_b.png", "F": good_F},
    ]  # fmt: skip


EXPECTED_ERRORS = {
    "missing-image": "not found",
    "malformed-F": "malformed F",
    "five-matches": "fewer than 8 matches",
    "no-texture": "fewer than 8 matches (0 with sift",
    "corrupt-image": "cannot read image",
}


def _read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _is_png(path: Path) -> bool:
    img = cv2.imread(str(path))
    return img is not None and img.shape[0] > 100 and img.shape[1] > 100


def test_synthetic_pair_has_exact_ground_truth():
    e = synthetic_entry(0)
    pa, pb = np.array(e["pts_a"]), np.array(e["pts_b"])
    d = symmetric_epipolar_distance(np.array(e["F"]), pa, pb)
    # 70% inliers with 0.1 px noise are all positives; the outliers are mostly not
    assert np.mean(d < 1.0) == pytest.approx(0.7, abs=0.05)
    assert len(pa) >= 150


SHARED_SCENES = ("kitti_seq2", "templeRing")


def test_end_to_end_report_on_shared_and_synthetic_pairs(tmp_path, shared_data, capsys):
    pairs = json.loads((shared_data / "pairs.json").read_text())
    picked = [next(p for p in pairs if p["scene"] == s) for s in SHARED_SCENES]
    for p in picked:  # the manifest lives in tmp_path, so give absolute image paths
        p["img_a"] = str(shared_data / p["img_a"])
        p["img_b"] = str(shared_data / p["img_b"])
    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps([*picked, synthetic_entry(0), *broken_entries(tmp_path)]))
    readme = tmp_path / "README.md"
    readme.write_text(
        "# x\n\n<!-- eval-table:start -->\nOLD-TABLE\n<!-- eval-table:end -->\n\ntail\n"
    )
    out, cache = tmp_path / "report", tmp_path / "cache"
    argv = ["--manifest", str(manifest), "--out", str(out), "--cache", str(cache),
            "--methods", "all", "--seeds", "0,1", "--readme", str(readme)]  # fmt: skip
    assert cli.main(argv) == 0
    err = capsys.readouterr().err
    assert "100%" in err and "run/s" in err  # the progress bar ran to the end

    methods = available_methods()
    assert {"sep4", "sep5", "cv-magsac", "cv-accurate"} <= set(methods)
    runs = _read_csv(out / "runs.csv")
    assert len(runs) == 3 * len(methods) * 2
    report = (out / "report.md").read_text()
    for m in methods:
        assert f"| {m} |" in report
    # every broken entry is listed with its reason
    section = report.split("## Pairs that could not be evaluated")[1]
    for name, reason in EXPECTED_ERRORS.items():
        line = next(x for x in section.splitlines() if x.startswith(f"| {name} |"))
        assert reason in line, line
    assert "## Scene `kitti_seq2`" in report and "## Scene `synthetic`" in report
    for fig in ("fig4_trials", "fig7_line_inliers", "fig8_line_homography_cdf", "error_cdf",
                "example_kitti_seq2", "example_templeRing", "example_synthetic"):  # fmt: skip
        assert _is_png(out / f"{fig}.png"), fig
        assert f"{fig}.png" in report

    def f_mean(pair_prefix: str, method: str) -> float:
        vals = [float(r["f_score"]) for r in runs
                if r["pair"].startswith(pair_prefix) and r["method"] == method]  # fmt: skip
        return float(np.mean(vals))

    for m in methods:
        # exact GT, 30% outliers: every estimator recovers the inliers
        assert f_mean("synthetic/", m) > 0.9, m
        # real pairs (a wiring or convention error, e.g. a transposed F, scores near 0)
        assert f_mean("kitti_seq2/", m) > 0.7, m
        assert f_mean("templeRing/", m) > 0.7, m
    # hypotheses: counted for ours (stage 1 + stage 2), n/a (empty) for OpenCV
    sep = [r for r in runs if r["method"] == "sep5"]
    assert all(int(r["hypotheses"]) == int(r["stage1_hypotheses"]) + int(r["stage2_hypotheses"])
               for r in sep)  # fmt: skip
    assert all(r["hypotheses"] == "" for r in runs if r["method"].startswith("cv-"))
    assert "| cv-ransac |" in report and "n/a" in report
    summary = json.loads((out / "summary.json").read_text())
    assert {c["metric"] for c in summary["comparisons"]} == {"f_score", "mean_error"}
    assert len(summary["errors"]) == len(EXPECTED_ERRORS)
    # the README got the overall table between its markers, the rest untouched
    text = readme.read_text()
    assert "OLD-TABLE" not in text and text.endswith("<!-- eval-table:end -->\n\ntail\n")
    assert "| sep5 |" in text and "| method | % inliers | F-score |" in text

    # second run: matches come from the cache (two shared pairs + the blank pair were cached)
    assert len(list(cache.glob("*.npz"))) == 3
    argv2 = ["--manifest", str(manifest), "--out", str(tmp_path / "r2"), "--cache", str(cache),
             "--methods", "cv-ransac", "--seeds", "0", "--no-progress"]  # fmt: skip
    assert cli.main(argv2) == 0
    cached = {r["pair"]: r["cached"] for r in _read_csv(tmp_path / "r2" / "pairs.csv")}
    shared_ids = [p.pair_id for p in load_manifest(manifest)[0] if p.scene in SHARED_SCENES]
    assert len(shared_ids) == 2
    assert cached == dict.fromkeys(shared_ids, "True") | {"synthetic/0": "False"}


def test_points_only_manifest_without_shared_data(tmp_path):
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps([synthetic_entry(3), *broken_entries(tmp_path)[2:3]]))
    out = tmp_path / "out"
    argv = ["--manifest", str(manifest), "--out", str(out), "--cache", "none",
            "--methods", "sep5,ransac8,cv-lmeds", "--seeds", "5", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    runs = _read_csv(out / "runs.csv")
    assert [r["method"] for r in runs] == ["sep5", "ransac8", "cv-lmeds"]
    assert all(float(r["f_score"]) > 0.9 for r in runs)
    assert "fewer than 8 matches (5 with" in (out / "report.md").read_text()


def test_nothing_evaluable_exits_1_and_still_reports(tmp_path):
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps(broken_entries(tmp_path)))
    out = tmp_path / "out"
    argv = ["--manifest", str(manifest), "--out", str(out), "--cache", str(tmp_path / "c"),
            "--methods", "ransac8", "--seeds", "0", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 1
    report = (out / "report.md").read_text()
    assert all(name in report for name in EXPECTED_ERRORS)


@pytest.mark.parametrize("content", ["{not json", '{"a": 1}'])
def test_unreadable_manifest_exits_2(tmp_path, content, capsys):
    manifest = tmp_path / "m.json"
    manifest.write_text(content)
    assert cli.main(["--manifest", str(manifest), "--out", str(tmp_path / "o")]) == 2
    assert "manifest" in capsys.readouterr().err
    assert cli.main(["--manifest", str(tmp_path / "absent.json")]) == 2


def test_bad_arguments_are_usage_errors(tmp_path):
    manifest = tmp_path / "m.json"
    manifest.write_text("[]")
    for extra in (["--methods", "nope"], ["--features", "surf"], ["--seeds", "a"],
                  ["--confidence", "1.5"], ["--baseline", "nope"]):  # fmt: skip
        with pytest.raises(SystemExit) as exc:
            cli.main(["--manifest", str(manifest), *extra])
        assert exc.value.code == 2


def test_manifest_relative_paths_and_duplicate_ids(tmp_path, shared_data):
    pairs, errors = load_manifest(shared_data / "pairs.json")
    assert len(pairs) == 167 and errors == []
    assert len({p.pair_id for p in pairs}) == 167
    assert all(p.img_a.is_file() and p.img_b.is_file() for p in pairs)
    entry = synthetic_entry(1)
    (tmp_path / "m.json").write_text(json.dumps([entry, entry]))
    twice, _ = load_manifest(tmp_path / "m.json")
    assert [p.pair_id for p in twice] == ["synthetic/1", "synthetic/1#1"]


def test_cache_key_follows_content_and_settings(tmp_path, shared_data):
    a = shared_data / "templeRing" / "templeR0001.png"
    b = shared_data / "templeRing" / "templeR0002.png"
    copy = tmp_path / "renamed.png"
    shutil.copy(a, copy)
    s = MatchSettings()
    assert cache_key(file_hash(a), file_hash(b), s) == cache_key(file_hash(copy), file_hash(b), s)
    assert cache_key(file_hash(a), file_hash(b), s) != cache_key(
        file_hash(a), file_hash(b), MatchSettings(ratio=0.75)
    )
    assert cache_key(file_hash(a), file_hash(b), s) != cache_key(file_hash(b), file_hash(a), s)
    with pytest.raises(ValueError, match="unknown features"):
        MatchSettings(features="surf")


@pytest.mark.parametrize("features", [detector_param(f) for f in ("sift", "orb", "akaze")])
def test_matches_are_distinct_and_every_detector_is_selectable(tmp_path, shared_data, features):
    from sepfm_ros.evaluation.manifest import PairSpec

    spec = PairSpec(
        "t",
        "templeRing",
        np.eye(3),
        img_a=shared_data / "templeRing" / "templeR0001.png",
        img_b=shared_data / "templeRing" / "templeR0002.png",
    )
    pm = MatchesCache(tmp_path / features, MatchSettings(features=features)).matches(spec)
    rows = np.hstack([pm.pts_a, pm.pts_b])
    assert len(pm.pts_a) > 50
    assert len(np.unique(rows, axis=0)) == len(rows)
    assert pm.size_a == (640, 480)


def test_a_method_that_raises_is_a_failed_run_not_a_crash():
    def boom(*_args):
        raise RuntimeError("solver exploded")

    r = _safe_run(Method("boom", "ours", "raises", boom), None, None, None, None, EvalConfig(), 0)
    assert r.F is None and "solver exploded" in r.status and math.isnan(r.ms)


def test_registry_holds_every_method_of_the_issue():
    expected = {"sep4", "sep5", "sep4-lmeds", "sep5-lmeds", "ransac7", "ransac8", "lmeds7",
                "lmeds8", "cv-ransac", "cv-lmeds", "cv-magsac", "cv-accurate",
                "poselib", "superansac", "superansac-adaptive"}  # fmt: skip
    assert set(REGISTRY) == expected


def test_ctrl_c_keeps_a_partial_report_of_whole_pairs(tmp_path):
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps([synthetic_entry(s) for s in range(40)]))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "sepfm_ros", "eval", "--manifest", str(manifest), "--out",
           str(out), "--cache", "none", "--methods", "all", "--seeds", "0,1,2"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stderr.readline()  # printed once the pairs are loaded, before the runs start
    assert "40 pairs x" in first, first
    # interrupt once the progress bar shows at least one whole pair of runs (of 40)
    per_pair_runs = len(available_methods()) * 3
    stderr: list[str] = []
    reader = threading.Thread(target=lambda: stderr.extend(iter(lambda: proc.stderr.read(1), "")))
    reader.start()
    deadline = time.monotonic() + 300
    while max(map(int, re.findall(r"(\d+)/\d+ \[", "".join(stderr))), default=0) < per_pair_runs:
        assert proc.poll() is None, "finished before it could be interrupted"
        assert time.monotonic() < deadline, "no pair finished within 300 s"
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=120)
    reader.join(timeout=10)
    err = "".join(stderr)
    assert proc.returncode == 130, err
    assert "interrupted; partial report" in err
    report = (out / "report.md").read_text()
    assert "**Interrupted** after" in report
    runs = _read_csv(out / "runs.csv")
    per_pair: dict[str, int] = {}
    for r in runs:
        per_pair[r["pair"]] = per_pair.get(r["pair"], 0) + 1
    assert 0 < len(per_pair) < 40
    assert set(per_pair.values()) == {len(available_methods()) * 3}  # whole pairs only


def test_readme_without_markers_is_an_error_not_a_silent_skip(tmp_path, capsys):
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps([synthetic_entry(2)]))
    readme = tmp_path / "README.md"
    readme.write_text("# no markers here\n")
    argv = ["--manifest", str(manifest), "--out", str(tmp_path / "o"), "--cache", "none",
            "--methods", "ransac8", "--seeds", "0", "--no-progress",
            "--readme", str(readme)]  # fmt: skip
    assert cli.main(argv) == 2
    assert "eval-table" in capsys.readouterr().err
    assert readme.read_text() == "# no markers here\n"
    assert (tmp_path / "o" / "report.md").is_file()  # the report itself is not lost
