"""`sepfm_ros eval --bags`: input bags with ground truth, bags written by `process`, bad bags."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from sepfm_ros.evaluation import cli
from sepfm_ros.evaluation.bags import find_bags, load_bag_pairs
from sepfm_ros.ros.commands import make_bag, process

pytestmark = pytest.mark.slow  # bags end to end through process and eval, about 50 s

REPO = Path(__file__).resolve().parents[2]
BUNDLED = REPO / "bags"


def _runs(out: Path) -> list[dict]:
    with open(out / "runs.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_bundled_input_bags_end_to_end(tmp_path):
    bags = find_bags(BUNDLED)
    assert {b.name for b in bags} >= {"synthetic_stereo", "synthetic_motion"}
    out = tmp_path / "out"
    argv = ["--bags", str(BUNDLED), "--out", str(out), "--cache", str(tmp_path / "cache"),
            "--methods", "sep5,cv-ransac", "--seeds", "0", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    runs = _runs(out)
    per_bag = {name: [r for r in runs if r["scene"] == name] for name in
               ("synthetic_stereo", "synthetic_motion")}  # fmt: skip
    for name, rows in per_bag.items():
        assert len(rows) >= 2 * 10, name  # >= 10 pairs x 2 methods
        # rendered scenes with exact cameras: every method recovers the positives
        assert all(float(r["f_score"]) > 0.9 for r in rows), name
        assert all(r["pair"].startswith(f"{name}@") for r in rows)
    # decoded frames went into the cache folder, so matches are cached by content
    assert list((tmp_path / "cache" / "bag_frames" / "synthetic_stereo").glob("*_a.png"))
    assert "## Scene `synthetic_stereo`" in (out / "report.md").read_text()


def test_processed_bag_uses_the_node_matches(tmp_path):
    processed = tmp_path / "processed"
    stereo = str(BUNDLED / "synthetic_stereo")
    assert process.main([stereo, "-o", str(processed), "-p", "seed:=0", "--quiet"]) == 0
    pairs, errors = load_bag_pairs(processed, tmp_path / "frames")
    assert errors == [] and len(pairs) == 12
    assert all(p.pts_a is not None and p.size_a is not None for p in pairs)
    out = tmp_path / "out"
    argv = ["--bags", str(processed), "--out", str(out), "--cache", "none",
            "--methods", "ransac8", "--seeds", "0", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    runs = _runs(out)
    assert len(runs) == 12 and all(float(r["f_score"]) > 0.9 for r in runs)


def test_bad_bags_are_reported_per_bag(tmp_path):
    folder = tmp_path / "bags"
    folder.mkdir()
    # a bag without ground truth (made from plain images)
    images = tmp_path / "images"
    images.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(images / f"{i}.png"), rng.integers(0, 255, (60, 80), dtype=np.uint8))
    assert make_bag.main(["--images", str(images), "-o", str(folder / "no_gt")]) == 0
    # a corrupt bag
    (folder / "corrupt").mkdir()
    (folder / "corrupt" / "metadata.yaml").write_text("this: [is not a bag")
    pairs, errors = load_bag_pairs(folder, tmp_path / "frames")
    assert pairs == []
    reasons = {e.pair_id: e.message for e in errors}
    assert "no /ground_truth/fundamental topic" in reasons["no_gt"]
    assert "corrupt" in reasons and reasons["corrupt"].startswith("bag ")
    _, missing = load_bag_pairs(tmp_path / "absent", tmp_path / "frames")
    assert "no bag found" in missing[0].message
    out = tmp_path / "out"
    argv = ["--bags", str(folder), "--out", str(out), "--cache", "none", "--methods", "ransac8",
            "--seeds", "0", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 1  # nothing evaluable, but a report listing why
    report = (out / "report.md").read_text()
    assert "| no_gt |" in report and "| corrupt |" in report


def test_eval_needs_a_manifest_or_bags():
    with pytest.raises(SystemExit) as exc:
        cli.main(["--out", "x"])
    assert exc.value.code == 2
