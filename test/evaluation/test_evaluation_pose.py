"""eval: relative-pose errors against ground-truth cameras (metrics, cameras file, report)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from sepfm_ros.evaluation import cli, metrics
from sepfm_ros.evaluation.manifest import load_cameras
from sepfm_ros.geometry.synthetic import make_pair


def test_pose_errors_on_exact_synthetic_pair():
    pair = make_pair(n_inliers=200, n_outliers=40, noise=0.0, seed=4)
    rot, tdir = metrics.pose_errors(pair.F, pair.pts1, pair.pts2, pair.P1, pair.P2, 1.0)
    assert rot < 1e-3 and tdir < 1e-2
    # a transposed F (a convention error) gives a wrong pose, not a small error
    rot_t, tdir_t = metrics.pose_errors(pair.F.T, pair.pts1, pair.pts2, pair.P1, pair.P2, 1.0)
    assert max(rot_t, tdir_t) > 1.0
    none = metrics.pose_errors(None, pair.pts1, pair.pts2, pair.P1, pair.P2, 1.0)
    assert none == (metrics.POSE_FAILURE_DEG, metrics.POSE_FAILURE_DEG)


def test_load_cameras_keeps_valid_entries(tmp_path):
    P = np.arange(12.0).reshape(3, 4)
    (tmp_path / "cameras.json").write_text(
        json.dumps({"a.png": P.tolist(), "bad.png": [[1, 2], [3, 4]], "nan.png": [["x"] * 4] * 3})
    )
    cams = load_cameras(tmp_path / "cameras.json")
    assert list(cams) == [(tmp_path / "a.png").resolve()]
    np.testing.assert_array_equal(cams[(tmp_path / "a.png").resolve()], P)
    assert load_cameras(tmp_path / "missing.json") == {}


def test_eval_report_has_pose_errors(tmp_path, shared_data):
    pairs = json.loads((shared_data / "pairs.json").read_text())
    picked = [
        next(p for p in pairs if p["scene"] == "kitti_seq2" and p["baseline"] == "medium"),
        next(p for p in pairs if p["scene"] == "templeRing"),
    ]
    for p in picked:
        p["img_a"] = str(shared_data / p["img_a"])
        p["img_b"] = str(shared_data / p["img_b"])
    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps(picked))
    out = tmp_path / "report"
    argv = ["--manifest", str(manifest), "--out", str(out), "--cache", "none",
            "--methods", "sep5,cv-magsac", "--seeds", "0", "--no-progress",
            "--cameras", str(shared_data / "cameras.json"), "--root", str(shared_data)]  # fmt: skip
    assert cli.main(argv) == 0
    with (out / "runs.csv").open() as f:
        runs = list(csv.DictReader(f))
    assert len(runs) == 4
    for r in runs:
        assert float(r["rotation_error_deg"]) < 3.0, r
        assert float(r["translation_error_deg"]) < 20.0, r
    report = (out / "report.md").read_text()
    assert "## Relative pose (pairs with GT cameras)" in report
    assert "| sep5 |" in report.split("## Relative pose")[1].split("##")[0]


def test_eval_without_cameras_has_no_pose_section(tmp_path, shared_data):
    pairs = json.loads((shared_data / "pairs.json").read_text())
    p = next(p for p in pairs if p["scene"] == "kitti_seq2")
    p["img_a"], p["img_b"] = str(shared_data / p["img_a"]), str(shared_data / p["img_b"])
    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps([p]))
    out = tmp_path / "report"
    argv = ["--manifest", str(manifest), "--out", str(out), "--cache", "none",
            "--methods", "sep5", "--seeds", "0", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    assert "## Relative pose" not in (out / "report.md").read_text()


@pytest.mark.parametrize("bad", ["[1, 2]", "not json"])
def test_bad_cameras_file_exits_2(tmp_path, bad):
    (tmp_path / "cams.json").write_text(bad)
    manifest = tmp_path / "manifest.json"
    manifest.write_text("[]")
    argv = ["--manifest", str(manifest), "--out", str(tmp_path / "o"), "--cameras",
            str(tmp_path / "cams.json"), "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 2
