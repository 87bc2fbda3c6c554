"""benchmarks/bench_docs.py: each benchmark rewrites only its own section of docs/benchmarks.md,
and README's headline table is cut from it (a missing marker is reported, nothing changes)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_docs  # noqa: E402


def test_sections_are_rewritten_in_place_and_others_kept(tmp_path):
    doc = tmp_path / "benchmarks.md"
    bench_docs.write_section("bench_outliers", "outliers, first run", doc)
    text = doc.read_text()
    assert text.startswith("# Benchmarks")
    for name in bench_docs.SECTIONS:  # every section has its place, in order
        assert text.count(bench_docs.markers(name)[0]) == 1
    order = [text.index(bench_docs.markers(n)[0]) for n in bench_docs.SECTIONS]
    assert order == sorted(order)
    assert "outliers, first run" in text and "Not generated yet" in text
    bench_docs.write_section("bench_estimators", "estimators table", doc)
    bench_docs.write_section("bench_outliers", "outliers, second run", doc)
    text = doc.read_text()
    assert "outliers, first run" not in text
    assert bench_docs.read_block(text, "bench_outliers") == "outliers, second run"
    assert bench_docs.read_block(text, "bench_estimators") == "estimators table"
    with pytest.raises(ValueError, match="unknown section"):
        bench_docs.write_section("bench_nothing", "x", doc)


def test_section_names_the_command_and_the_machine():
    text = bench_docs.section(
        "bench_outliers", "Title", bench_docs.command_line("bench_outliers.py", ["--step", "8"]),
        "| a |",
    )  # fmt: skip
    assert text.startswith("## Title")
    assert "`python benchmarks/bench_outliers.py --step 8`" in text
    assert "CPUs (" in text and "numpy " in text and "OpenCV " in text


def test_headline_is_copied_into_readme_markers(tmp_path):
    doc, readme = tmp_path / "benchmarks.md", tmp_path / "README.md"
    begin, end = bench_docs.markers(bench_docs.HEADLINE)
    bench_docs.write_section("bench_estimators", f"{begin}\n| sep5 | 0.98 |\n{end}\nmore", doc)
    readme.write_text(f"# Title\n\n{begin}\nold table\n{end}\n\nrest\n")
    assert bench_docs.update_headline(readme, doc) is None
    assert readme.read_text() == f"# Title\n\n{begin}\n| sep5 | 0.98 |\n{end}\n\nrest\n"


def test_missing_headline_markers_are_reported_and_nothing_changes(tmp_path):
    doc, readme = tmp_path / "benchmarks.md", tmp_path / "README.md"
    readme.write_text("# no markers\n")
    assert "does not exist yet" in bench_docs.update_headline(readme, doc)
    bench_docs.write_section("bench_estimators", "no headline block here", doc)
    assert "no headline block" in bench_docs.update_headline(readme, doc)
    begin, end = bench_docs.markers(bench_docs.HEADLINE)
    bench_docs.write_section("bench_estimators", f"{begin}\n| t |\n{end}", doc)
    problem = bench_docs.update_headline(readme, doc)
    assert f"has no {begin} ... {end} markers" in problem
    assert readme.read_text() == "# no markers\n"
    assert bench_docs.main(["--headline", "--readme", str(readme), "--doc", str(doc)]) == 1
