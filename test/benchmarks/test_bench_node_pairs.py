"""benchmarks/bench_node_pairs.py and bench_race_lines.py on two consecutive pairs of each shared
sequence: the node's matching, the printed tables with figures in range, and the docs sections
they write."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_docs  # noqa: E402
import bench_node_pairs  # noqa: E402
import bench_race_lines  # noqa: E402

from sepfm_ros.evaluation.methods import superansac_methods  # noqa: E402
from sepfm_ros.geometry import DEFAULT_METHOD  # noqa: E402
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig  # noqa: E402


def test_pairs_are_consecutive_frames_matched_by_the_node_pipeline(shared_data):
    pairs = bench_node_pairs.node_pairs("kitti", shared_data, max_pairs=2, progress=False)
    assert [p.pair_id for p in pairs] == [
        "kitti_seq2/left/000000.png -> kitti_seq2/left/000001.png",
        "kitti_seq2/left/000049.png -> kitti_seq2/left/000050.png",
    ]
    first = pairs[0]
    img_a = bench_node_pairs.node_image(shared_data / "kitti_seq2/left/000000.png")
    img_b = bench_node_pairs.node_image(shared_data / "kitti_seq2/left/000001.png")
    m = Pipeline(PipelineConfig()).match(img_a, img_b).matches
    assert np.array_equal(m.pts_a, first.matches.pts_a)
    assert np.array_equal(m.pts_b, first.matches.pts_b)
    assert first.size_a == (1241, 376)
    # the GT F from the cameras explains most matches of a small forward step
    assert first.positives.mean() > 0.5


def test_two_pairs_per_sequence_print_and_write_docs(shared_data, tmp_path, capsys):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(bench_docs.empty_document())
    # SupeRANSAC's two entries too where it is installed (test_superansac.py: required by CI)
    names = [DEFAULT_METHOD, "cv-magsac", *superansac_methods()]
    methods = ",".join(names)
    argv = ["--data", str(shared_data), "--max-pairs", "2", "--seeds", "0", "--methods", methods,
            "--write-docs", "--doc", str(doc)]  # fmt: skip
    assert bench_node_pairs.main(argv) == 0
    out = capsys.readouterr().out
    assert out.count("2 pairs x 1 seeds") == 2
    rows = re.findall(
        r"^\| (\S+)(?: \(default\))? \| (\d\.\d{3}) ± \S+ \| (\S+) \| (\S+) \| \S+ \| (\S+) \| "
        r"(\S+) / (\S+) \| (\S+) \| (\S+) \| (\S+) \|$",
        out,
        re.M,
    )
    assert [r[0] for r in rows] == names * 2
    for name, f, ok, below, rot, dir_med, dir_p90, hyp, ms, ratio in rows:
        assert 0.0 <= float(f) <= 1.0
        # a small forward step: the pose from a good F is within a few degrees of the cameras'
        assert 0.0 <= float(dir_med) <= float(dir_p90) <= 180.0
        if not name.startswith("superansac"):
            # SupeRANSAC's answers are what the benchmark reports, not what this test checks: on
            # KITTI 49->50 it returns a wrong F (translation 151 degrees off) at 1 px
            # (templeRing's first two views are poorly conditioned for the pose: ransac7's
            # answer, which sep4 gives there through the escape, is 4.1 deg off at an F-score of
            # 0.970, against USAC_MAGSAC's 0.9 deg at 0.963)
            assert float(rot) < 5.0 and float(dir_med) < 25.0
        assert 0.0 <= float(ok) <= float(below) <= 100.0
        assert float(ms) > 0
        assert (hyp == "n/a") == (name == "cv-magsac")
        if name == "cv-magsac":
            assert ratio == "1.00"
    # per sequence, the default method's compiled work against its required ratio
    notes = re.findall(
        r"^Compiled work .*: median (\d+\.\d\d) ms per pair, \S+x USAC_MAGSAC's median; the "
        r"method's median (\d+\.\d\d) ms is \S+x\. Required: at most (1\.95|1\.50)x "
        r"\((\d+\.\d\d) ms\); the compiled work alone is (above|within) it\.$",
        out,
        re.M,
    )
    assert [n[2] for n in notes] == ["1.95", "1.50"]  # KITTI, then templeRing
    for compiled, measured, _, allowed, verdict in notes:
        assert 0 < float(compiled) <= float(measured)
        assert verdict == ("above" if float(compiled) > float(allowed) else "within")
    body = bench_docs.read_block(doc.read_text(), "bench_node_pairs")
    assert body.startswith("## Node pipeline on consecutive frames")
    assert "`python benchmarks/bench_node_pairs.py --data" in body
    assert body.count("| cv-magsac |") == 2
    assert "Not generated yet" in bench_docs.read_block(doc.read_text(), "bench_race_lines")


def test_race_lines_two_configurations_three_seeds(shared_data, tmp_path, capsys):
    doc = tmp_path / "benchmarks.md"
    label = "pool by support 1.0"
    argv = ["--sets", "kitti", "--max-pairs", "2", "--seeds", "0,1,2", "--configs", label,
            "--write-docs", "--doc", str(doc)]  # fmt: skip
    assert bench_race_lines.main(argv) == 0
    out = capsys.readouterr().out
    assert "**kitti**: 2 consecutive pairs" in out
    current = re.search(rf"^\| {re.escape(bench_race_lines.CURRENT)} \| (\S+) \| — \|", out, re.M)
    assert current and 0.0 <= float(current.group(1)) <= 1.0
    row = re.search(rf"^\| {label} \| (\S+) \| (\S+) / (\S+) / (\S+) \| (\S+) \|", out, re.M)
    assert row
    assert all(-1.0 <= float(row.group(i)) <= 1.0 for i in (2, 3, 4))
    assert "Seed noise of the defaults: mean F-score per seed" in out
    body = bench_docs.read_block(doc.read_text(), "bench_race_lines")
    assert body.startswith(f"## Race pooling and line thresholds of {DEFAULT_METHOD}")
    assert "--configs" in body and "**kitti**" in body
