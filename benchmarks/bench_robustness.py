"""Robustness report: runs the robustness tests and writes their figures as Markdown.

    python benchmarks/bench_robustness.py [--fuzz-raw 10000] [--fuzz-compressed 3000]
        [--overload-s 60] [--overload-runs 1] [--kill-trials 20] [--out FILE.md] [--write-docs]

The default sizes are the same as the default test run (CI runs these tests in full:
test/ros/test_robustness_live.py, test/ros/test_robustness_bags.py,
test/geometry/test_degeneracy.py);
larger values make longer soak runs. The tests print each figure as ``[robustness] ...`` and,
through the environment variable SEPFM_ROBUSTNESS_REPORT, hand them to this script, which writes
the report, prints it and with ``--write-docs`` puts it in docs/benchmarks.md (bench_docs.py).
Exit code: pytest's (non-zero when a pass criterion failed; the report is written anyway).

The overload bound (end-to-end latency p95 under twice the unloaded p95) is a timing figure:
the test asserts only that latency stays bounded (3x: no queue), and this report checks the 2x
bound. ``--overload-runs N`` repeats the overload test N - 1 more times after the full run and
tabulates every run against the bound (one 60 s run says little on a shared 2-core machine).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_docs

REPO = Path(__file__).resolve().parent.parent
TESTS = [
    "test/ros/test_robustness_live.py",
    "test/ros/test_robustness_bags.py",
    "test/geometry/test_degeneracy.py",
]

TITLES = {
    "fuzz_raw": "Fuzz: malformed sensor_msgs/Image to the live node",
    "fuzz_compressed": "Fuzz: malformed sensor_msgs/CompressedImage to the live node",
    "degenerate_geometry": "Degenerate geometry through the node (status on ~/estimate)",
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
    lines = [header, ""]
    for section in [*TITLES, *sorted(set(figures) - set(TITLES))]:
        if section not in figures:
            continue
        lines += [f"### {TITLES.get(section, section)}", "", "| figure | value |", "|---|---|"]
        for key, value in figures[section].items():
            lines.append(f"| {key} | {_value(value).replace('|', '/')} |")
        lines.append("")
    return "\n".join(lines)


OVERLOAD_BOUND = 2.0  # issue 6: loaded p95 < 2 x unloaded p95


def overload_table(runs: list[dict]) -> str:
    """Markdown table of repeated overload runs against the 2x bound."""
    lines = [
        "### Overload: repeated runs against the 2x latency bound",
        "",
        "| run | load (1 min) | processing rate Hz | p95 unloaded ms | p95 loaded ms | ratio "
        "| node-side ratio | p95 at half rate ms | ratio to it | recovery answered | within 2x |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for k, r in enumerate(runs, 1):
        ok = r["latency_p95_ratio"] < OVERLOAD_BOUND
        lines.append(
            f"| {k} | {r.get('load_average_1min', '?')} | {r.get('processing_rate_hz', '?')} "
            f"| {r['latency_p95_ms_unloaded']} | {r['latency_p95_ms_loaded']} "
            f"| {r['latency_p95_ratio']} | {r.get('node_latency_p95_ratio', '?')} "
            f"| {r.get('latency_p95_ms_half_rate', '?')} "
            f"| {r.get('latency_p95_ratio_to_half_rate', '?')} "
            f"| {r.get('recovery_pairs_answered', '?')}/{r.get('recovery_pairs_sent', '?')} "
            f"| {'yes' if ok else 'NO'} |"
        )
    ratios = [r["latency_p95_ratio"] for r in runs]
    within = sum(x < OVERLOAD_BOUND for x in ratios)
    lines += [
        "",
        f"{within} of {len(runs)} runs within the bound; ratio min {min(ratios)}, "
        f"median {sorted(ratios)[len(ratios) // 2]}, max {max(ratios)}. The node-side ratio "
        "uses the node's own latency (receipt to publish, from ~/estimate), without the "
        "sending and receiving test process. The ratio to half rate uses the p95 of a steady "
        "stream at half the processing rate (the recovery phase) as the unloaded reference "
        "instead of one pair at a time; 'within 2x' is judged on the stricter first ratio.",
        "",
    ]
    return "\n".join(lines)


def _pytest(tests: list[str], env: dict, extra: list[str] = ()) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider", *extra, *tests],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fuzz-raw", type=int, default=10000)
    p.add_argument("--fuzz-compressed", type=int, default=3000)
    p.add_argument("--overload-s", type=float, default=60.0)
    p.add_argument("--overload-runs", type=int, default=1, help="overload test runs in all")
    p.add_argument("--kill-trials", type=int, default=20)
    p.add_argument("--out", type=Path, default=None, help="also write the report to this file")
    p.add_argument(
        "--write-docs", action="store_true", help="rewrite this section of docs/benchmarks.md"
    )
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
        res = _pytest(TESTS, env)
        sys.stderr.write(res.stdout[-4000:] + res.stderr[-2000:])
        figures = json.loads(report.read_text()) if report.is_file() else {}
        overload_runs = [figures["overload"]] if "overload" in figures else []
        returncode = res.returncode
        for k in range(1, args.overload_runs):
            one = Path(tmp) / f"overload{k}.json"
            print(f"overload run {k + 1} of {args.overload_runs} ...", file=sys.stderr, flush=True)
            again = _pytest(
                [TESTS[0]], dict(env, SEPFM_ROBUSTNESS_REPORT=str(one)), ["-k", "overload"]
            )
            sys.stderr.write(again.stdout[-1500:])
            returncode = returncode or again.returncode
            if one.is_file():
                overload_runs.append(json.loads(one.read_text())["overload"])
        elapsed = time.monotonic() - t0
    plane = [line.split("] ", 1)[1] for line in res.stdout.splitlines() if "] plane check" in line]
    if plane:
        figures["dominant_plane_check"] = {f"scene {k + 1}": t for k, t in enumerate(plane)}
    summary = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else "no output"
    details = (
        f"Ran {elapsed:.0f} s, load average (1 min) {load_before:.2f} before; pytest: {summary}. "
        "Sizes: "
        f"{args.fuzz_raw} + {args.fuzz_compressed} malformed messages, {args.overload_s:g} s "
        f"overload, {args.kill_trials} SIGKILL trials. Memory is the node process's resident set "
        "size (VmRSS); latency is end to end (pair published by the test -> ~/estimate "
        "received)."
    )
    command = bench_docs.command_line("bench_robustness.py", argv)
    text = render(figures, details)
    if overload_runs:
        text += "\n" + overload_table(overload_runs)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        header = f"Produced by `{command}` on {bench_docs.machine_description()}.\n\n"
        args.out.write_text(header + text + "\n")
        print(f"\nwrote {args.out}", file=sys.stderr)
    if args.write_docs:
        section = bench_docs.section("bench_robustness", "Robustness", command, text)
        path = bench_docs.write_section("bench_robustness", section)
        print(f"\nwrote {path}", file=sys.stderr)
    return returncode


if __name__ == "__main__":
    sys.exit(main())
