"""Robustness report (issue 6): runs the robustness tests and writes their figures as Markdown.

    python benchmarks/bench_robustness.py [--fuzz-raw 10000] [--fuzz-compressed 3000]
        [--overload-s 60] [--kill-trials 20] [--out docs/robustness.md]

The default sizes are the issue's and the same as the default test run (CI runs these tests in
full: test/test_robustness_live.py, test/test_robustness_bags.py, test/test_degeneracy.py);
larger values make longer soak runs. The tests print each figure as ``[robustness] ...`` and,
through the environment variable SEPFM_ROBUSTNESS_REPORT, hand them to this script, which writes
the report (default docs/robustness.md) and prints it. Exit code: pytest's (non-zero when a pass
criterion failed; the report is written anyway).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TESTS = ["test/test_robustness_live.py", "test/test_robustness_bags.py", "test/test_degeneracy.py"]

TITLES = {
    "fuzz_raw": "Fuzz: malformed sensor_msgs/Image to the live node",
    "fuzz_compressed": "Fuzz: malformed sensor_msgs/CompressedImage to the live node",
    "degenerate_geometry": "Degenerate geometry through the node (status on ~/estimate_info)",
    "camera_stop": "Stereo: the right camera stops for 3 s, then returns",
    "dds_peer_churn": "A DDS subscriber process started and SIGKILLed repeatedly",
    "overload": "Overload: pairs at twice the processing rate",
    "process_sigkill": "`sepfm_ros process` killed with SIGKILL at random points",
    "replay_irregular_stamps": "`sepfm_ros replay` of a bag with a gap, a repeat and a step back",
}


def _value(v) -> str:
    if isinstance(v, dict):
        return ", ".join(f"{k}: {x}" for k, x in v.items())
    if isinstance(v, list):
        return " ".join(str(x) for x in v)
    return str(v)


def render(figures: dict, header: str) -> str:
    lines = ["# Robustness report", "", header, ""]
    for section in [*TITLES, *sorted(set(figures) - set(TITLES))]:
        if section not in figures:
            continue
        lines += [f"## {TITLES.get(section, section)}", "", "| figure | value |", "|---|---|"]
        for key, value in figures[section].items():
            lines.append(f"| {key} | {_value(value).replace('|', '/')} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fuzz-raw", type=int, default=10000)
    p.add_argument("--fuzz-compressed", type=int, default=3000)
    p.add_argument("--overload-s", type=float, default=60.0)
    p.add_argument("--kill-trials", type=int, default=20)
    p.add_argument("--out", type=Path, default=REPO / "docs" / "robustness.md")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "figures.json"
        env = dict(
            os.environ,
            SEPFM_ROBUSTNESS_REPORT=str(report),
            SEPFM_FUZZ_RAW=str(args.fuzz_raw),
            SEPFM_FUZZ_COMPRESSED=str(args.fuzz_compressed),
            SEPFM_OVERLOAD_S=str(args.overload_s),
            SEPFM_KILL_TRIALS=str(args.kill_trials),
        )
        t0 = time.monotonic()
        load_before = os.getloadavg()[0]
        # the degeneracy test prints its counts; capture them from pytest's output
        res = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider", *TESTS],
            cwd=REPO,
            env=env,
            capture_output=True,
            text=True,
        )
        elapsed = time.monotonic() - t0
        sys.stderr.write(res.stdout[-4000:] + res.stderr[-2000:])
        figures = json.loads(report.read_text()) if report.is_file() else {}
    plane = [line.split("] ", 1)[1] for line in res.stdout.splitlines() if "] plane check" in line]
    if plane:
        figures["dominant_plane_check"] = {f"scene {k + 1}": t for k, t in enumerate(plane)}
    summary = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else "no output"
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True
    ).stdout.strip()
    header = (
        f"Produced by `python benchmarks/bench_robustness.py` at commit {commit or '?'} "
        f"on {platform.node()} "
        f"({os.cpu_count()} CPUs) in {elapsed:.0f} s, load average (1 min) {load_before:.2f} "
        f"before and {os.getloadavg()[0]:.2f} after; pytest: {summary}. "
        "Sizes: "
        f"{args.fuzz_raw} + {args.fuzz_compressed} malformed messages, {args.overload_s:g} s "
        f"overload, {args.kill_trials} SIGKILL trials. Memory is the node process's resident set "
        "size (VmRSS); latency is end to end (pair published by the test -> ~/estimate_info "
        "received)."
    )
    text = render(figures, header)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text + "\n")
    print(text)
    print(f"\nwrote {args.out}", file=sys.stderr)
    return res.returncode


if __name__ == "__main__":
    sys.exit(main())
