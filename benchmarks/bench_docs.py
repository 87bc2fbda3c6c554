"""docs/benchmarks.md, written by the benchmark scripts themselves: each script owns one section
between ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->`` and rewrites it with ``--write-docs``,
headed by the command that produced it and the machine it ran on. README's headline table is
cut from the block between ``<!-- headline:begin -->`` and ``<!-- headline:end -->`` of
docs/benchmarks.md (written by bench_estimators.py) into the same markers in README.md.

    python benchmarks/bench_docs.py --headline [--readme README.md]   # only re-cut the headline
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import platform
import shlex
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO

REPO = Path(__file__).resolve().parent.parent
BENCH_DOC = REPO / "docs" / "benchmarks.md"
README = REPO / "README.md"
HEADLINE = "headline"
# the sections in document order, and the command that (re)generates each
SECTIONS = {
    "bench_estimators": "python benchmarks/bench_estimators.py --write-docs",
    "bench_lines": "python benchmarks/bench_lines.py --write-docs",
    "bench_ablation": "python benchmarks/bench_ablation.py --write-docs",
    "bench_race_lines": "python benchmarks/bench_race_lines.py --write-docs",
    "bench_outliers": "python benchmarks/bench_outliers.py --write-docs",
    "bench_node": "python benchmarks/bench_node.py --write-docs",
    "bench_node_pairs": "python benchmarks/bench_node_pairs.py --write-docs",
    "bench_downscale": "python benchmarks/bench_downscale.py --write-docs",
    "bench_robustness": "python benchmarks/bench_robustness.py --write-docs",
    "bench_rectify": "python benchmarks/bench_rectify.py --write-docs",
    "bench_engines": "python benchmarks/bench_engines.py --write-docs",
    "bench_audit": "python benchmarks/bench_audit.py --write-docs",
    "bench_rigs": "python benchmarks/bench_rigs.py --write-docs",
    "bench_netns": "python benchmarks/bench_netns.py --write-docs",
    "bench_pose_covariance": "python benchmarks/bench_pose_covariance.py --write-docs",
    "bench_graph": "python benchmarks/bench_graph.py --write-docs",
    "bench_self_heal": "python benchmarks/bench_self_heal.py --write-docs",
}
PREAMBLE = """# Benchmarks

Every section below is written by the script named in its first line, on the machine described
there; rerun that command to regenerate it (other sections stay as they are). Times move with
the machine's load: compare methods within one table (same run, same matches), not across runs.
"""


class MarkerError(ValueError):
    """A document lacks the begin/end markers of a block."""


def markers(name: str) -> tuple[str, str]:
    return f"<!-- {name}:begin -->", f"<!-- {name}:end -->"


def machine_description() -> str:
    """One line: CPUs (count and model), Python, numpy, OpenCV and numba versions, load."""
    import cv2
    import numba
    import numpy

    model = platform.processor() or "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (
        f"{os.cpu_count()} CPUs ({model}), Python {platform.python_version()}, "
        f"numpy {numpy.__version__}, OpenCV {cv2.__version__}, numba {numba.__version__}; "
        f"load average {load:.1f} at the end of the run"
    )


class Tee(io.TextIOBase):
    """A text stream that writes to ``stream`` and keeps a copy (``text``)."""

    def __init__(self, stream: TextIO) -> None:
        self.stream, self.copy = stream, io.StringIO()

    def write(self, s: str) -> int:
        self.copy.write(s)
        return self.stream.write(s)

    def flush(self) -> None:
        self.stream.flush()

    @property
    def text(self) -> str:
        return self.copy.getvalue()


@contextlib.contextmanager
def captured_stdout() -> Iterator[Tee]:
    """Print as usual and keep a copy of everything printed (for a section's body)."""
    tee = Tee(sys.stdout)
    with contextlib.redirect_stdout(tee):
        yield tee


def command_line(script: str, argv: list[str] | None) -> str:
    """The command that ran ``script`` with ``argv`` (default: this process's arguments)."""
    args = sys.argv[1:] if argv is None else argv
    return shlex.join(["python", f"benchmarks/{script}", *args])


def section(name: str, title: str, command: str, body: str) -> str:
    """A section: title, the command that produced it, the machine, then ``body``."""
    return f"## {title}\n\nProduced by `{command}` on {machine_description()}.\n\n{body.strip()}\n"


def replace_block(text: str, name: str, content: str) -> str:
    """``text`` with the block between ``name``'s markers replaced by ``content``.

    Raises:
        MarkerError: a marker is missing or the end comes before the begin.
    """
    begin, end = markers(name)
    i, j = text.find(begin), text.find(end)
    if i < 0 or j < i:
        raise MarkerError(f"no {begin} ... {end} block")
    return text[: i + len(begin)] + "\n" + content.strip() + "\n" + text[j:]


def read_block(text: str, name: str) -> str:
    """The content between ``name``'s markers (MarkerError when missing)."""
    begin, end = markers(name)
    i, j = text.find(begin), text.find(end)
    if i < 0 or j < i:
        raise MarkerError(f"no {begin} ... {end} block")
    return text[i + len(begin) : j].strip()


def empty_document() -> str:
    """docs/benchmarks.md before any script ran: the preamble and one placeholder per section."""
    parts = [PREAMBLE]
    for name, command in SECTIONS.items():
        begin, end = markers(name)
        parts.append(f"{begin}\n_Not generated yet: run `{command}`._\n{end}\n")
    return "\n".join(parts)


def write_section(name: str, content: str, path: Path = BENCH_DOC) -> Path:
    """(Re)write section ``name`` of docs/benchmarks.md (created when missing)."""
    if name not in SECTIONS:
        raise ValueError(f"unknown section {name!r}; known: {sorted(SECTIONS)}")
    text = path.read_text() if path.is_file() else empty_document()
    try:
        text = replace_block(text, name, content)
    except MarkerError:  # a section added after the file was made: append it
        begin, end = markers(name)
        text = text.rstrip("\n") + f"\n\n{begin}\n{content.strip()}\n{end}\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def update_headline(readme: Path = README, doc: Path = BENCH_DOC) -> str | None:
    """Copy the headline block of ``doc`` into ``readme``'s headline markers.

    Returns None when done, else why not (missing file or markers), meant to be printed; the
    files are left unchanged then.
    """
    begin, end = markers(HEADLINE)
    if not doc.is_file():
        return f"{doc} does not exist yet; run {SECTIONS['bench_estimators']}"
    if not readme.is_file():
        return f"{readme} does not exist"
    try:
        table = read_block(doc.read_text(), HEADLINE)
    except MarkerError:
        return f"{doc} has no headline block yet; run {SECTIONS['bench_estimators']}"
    try:
        text = replace_block(readme.read_text(), HEADLINE, table)
    except MarkerError:
        return (
            f"{readme} has no {begin} ... {end} markers; put them where the headline table "
            "belongs, then rerun: python benchmarks/bench_docs.py --headline"
        )
    readme.write_text(text)
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--headline", action="store_true", help="copy the headline table to README")
    ap.add_argument("--readme", type=Path, default=README)
    ap.add_argument("--doc", type=Path, default=BENCH_DOC)
    a = ap.parse_args(argv)
    if not a.headline:
        ap.print_help()
        return 0
    problem = update_headline(a.readme, a.doc)
    if problem:
        print(f"headline not updated: {problem}", file=sys.stderr)
        return 1
    print(f"updated the headline table of {a.readme} from {a.doc}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
