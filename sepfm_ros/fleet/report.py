"""The fleet report: ``report.md`` beside ``bags.csv``, with one PNG per rig in ``plots/``.

Rigs whose calibration check raised WARN or ERROR in any bag come first (worst first), each with
its drift over time across all its bags (per-pair rotation against the calibration, the check's
window median and thresholds, bag boundaries) and its bags' rows; then the rigs that held, the
rigs without calibrated stereo (answer statistics only), and the bags that could not be read,
with the reason.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from sepfm_ros.fleet.records import FLAG_LEVELS, LEVEL_RANK, Thresholds

REPORT_MD = "report.md"
PLOTS = "plots"


def _f(text: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def _fmt(value: float, digits: int = 3) -> str:
    return "" if math.isnan(value) else f"{value:.{digits}f}"


@dataclass
class RigSummary:
    """One rig's bags (CSV rows, in time order) and pairs, and its worst decision."""

    name: str
    rows: list[dict[str, str]] = field(default_factory=list)
    pairs: list[dict[str, str]] = field(default_factory=list)

    @property
    def worst(self) -> str:
        levels = [r.get("worst_level", "") for r in self.rows]
        return max(levels, key=lambda lv: LEVEL_RANK.get(lv, -1), default="")

    @property
    def flagged(self) -> bool:
        return self.worst in FLAG_LEVELS

    @property
    def calibrated(self) -> bool:
        return any(r.get("calibrated") == "True" for r in self.rows)

    def first_flag(self) -> dict[str, str] | None:
        """The earliest bag row with a flag."""
        flagged = [r for r in self.rows if r.get("first_flagged_utc")]
        return min(flagged, key=lambda r: r["first_flagged_utc"]) if flagged else None


def group_rigs(rows: list[dict[str, str]], pairs: list[dict[str, str]]) -> list[RigSummary]:
    """Rigs of the answered bags (by their ``rig`` name), flagged first, worst first."""
    rigs: dict[str, RigSummary] = {}
    rig_of_bag = {}
    for r in rows:
        if r.get("state") != "done":
            continue
        rigs.setdefault(r["rig"], RigSummary(r["rig"])).rows.append(r)
        rig_of_bag[r["bag"]] = r["rig"]
    for p in pairs:
        rig = rig_of_bag.get(p.get("bag", ""))
        if rig is not None:
            rigs[rig].pairs.append(p)
    for rig in rigs.values():
        rig.rows.sort(key=lambda r: r.get("start_utc", ""))
        rig.pairs.sort(key=lambda p: int(p["stamp_ns"]))
    return sorted(
        rigs.values(),
        key=lambda g: (-LEVEL_RANK.get(g.worst, -1) if g.flagged else 0, not g.calibrated, g.name),
    )


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "rig"


def plot_rig(rig: RigSummary, path: Path, thresholds: Thresholds) -> None:
    """PNG of a rig's drift over time: per-pair rotation against the calibration (dots), the
    check's window median (line), thresholds, flagged pairs in red, bag starts dashed. A rig
    without calibrated stereo shows its inliers' epipolar error instead."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [datetime.fromtimestamp(int(p["stamp_ns"]) / 1e9, timezone.utc) for p in rig.pairs]
    fig, ax = plt.subplots(figsize=(9, 3.2))
    if rig.calibrated:
        rot = [_f(p["rotation_error_deg"]) for p in rig.pairs]
        win = [_f(p["window_rotation_deg"]) for p in rig.pairs]
        bad = [p.get("level") in FLAG_LEVELS for p in rig.pairs]
        ax.plot(t, rot, ".", ms=4, color="0.45", label="pair")
        ax.plot(t, win, "-", lw=1.5, color="C0", label="check's window median")
        flagged_t = [x for x, b in zip(t, bad, strict=True) if b]
        flagged_r = [x for x, b in zip(win, bad, strict=True) if b]
        if flagged_t:
            ax.plot(flagged_t, flagged_r, "o", ms=4, color="red", label="WARN/ERROR")
        ax.axhline(thresholds.warn_rotation_deg, color="orange", ls="--", lw=1, label="WARN")
        ax.axhline(thresholds.error_rotation_deg, color="red", ls="--", lw=1, label="ERROR")
        ax.set_ylabel("rotation vs calibration (deg)")
    else:
        err = [_f(p["inlier_error_px"]) for p in rig.pairs]
        ax.plot(t, err, ".", ms=4, color="C2", label="inliers' median epipolar error")
        ax.set_ylabel("epipolar error (px)")
    for r in rig.rows:
        if r.get("start_utc"):
            ax.axvline(datetime.fromisoformat(r["start_utc"]), color="0.7", ls=":", lw=1)
        if r.get("drift_start_utc"):
            ax.axvline(datetime.fromisoformat(r["drift_start_utc"]), color="red", lw=1)
    ax.set_title(f"{rig.name}: {rig.worst or 'no calibration check'}")
    ax.set_xlabel("time (UTC); dotted: a bag starts; red: the drift starts")
    ax.legend(fontsize=7, loc="upper left")
    fig.autofmt_xdate()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _correction_text(row: dict[str, str]) -> str:
    """A flagged bag's corrected rotation with its 95 % interval, or why there is none."""
    if not row.get("correction_pairs"):
        return row.get("correction_reason", "").replace("|", "/")
    parts = []
    for axis in ("pitch", "yaw", "roll"):
        value, half = _f(row[f"correction_{axis}_deg"]), _f(row[f"correction_{axis}_ci95_deg"])
        parts.append(f"{axis} {value:+.3f} ± {half:.3f}")
    kept = "" if row.get("correction_yaw_determined") == "True" else ", yaw kept"
    return f"{', '.join(parts)} ({row['correction_pairs']} pairs{kept})"


def _bag_table(rig: RigSummary) -> list[str]:
    lines = [
        "| bag | start (UTC) | s | pairs | with F | median inliers | inlier error (px) | "
        "rotation drift (deg) | worst | drift starts | first flagged | correction (deg) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|---|---|---|",
    ]
    for r in rig.rows:
        start = f"{r['drift_start_utc']} ({_fmt(_f(r['drift_start_s']), 1)} s in)"
        flag = f"{r['first_flagged_utc']} ({_fmt(_f(r['first_flagged_s']), 1)} s in)"
        lines.append(
            f"| {Path(r['bag']).name} | {r['start_utc']} | {_fmt(_f(r['duration_s']), 1)} | "
            f"{r['pairs']} | {r['pairs_with_f']} | {_fmt(_f(r['median_inliers']), 0)} | "
            f"{_fmt(_f(r['median_inlier_error_px']), 2)} | {_fmt(_f(r['rotation_drift_deg']))} "
            f"| {r['worst_level'] or '-'} | {start if r['drift_start_utc'] else ''} | "
            f"{flag if r['first_flagged_utc'] else ''} | {_correction_text(r)} |"
        )
    return lines


def write_report(
    out: Path,
    rows: list[dict[str, str]],
    pairs: list[dict[str, str]],
    thresholds: Thresholds,
    warnings: list[str],
) -> Path:
    """Write ``report.md`` and its PNGs into ``out``; returns the report's path."""
    rigs = group_rigs(rows, pairs)
    failed = [r for r in rows if r.get("state") != "done"]
    flagged = [g for g in rigs if g.flagged]
    (out / PLOTS).mkdir(parents=True, exist_ok=True)
    lines = [
        "# Fleet calibration audit",
        "",
        f"{len(rows)} bags, {len(rigs)} rigs: **{len(flagged)} rig(s) flagged** "
        f"(calibration check WARN or ERROR), {len(failed)} bag(s) could not be read. "
        f"Thresholds: WARN over {thresholds.warn_rotation_deg} deg, ERROR over "
        f"{thresholds.error_rotation_deg} deg of rotation against the calibration (window "
        "median). The table behind this page is `bags.csv`, every pair is in `pairs.csv`.",
        "",
    ]
    if warnings:
        lines += ["## Warnings", ""] + [f"- {w}" for w in warnings] + [""]
    lines += [
        "## Rigs",
        "",
        "| rig | cameras | bags | worst | first flagged | max window rotation (deg) |",
        "|---|---|---:|---|---|---:|",
    ]
    for g in rigs:
        first = g.first_flag()
        where = f"{Path(first['bag']).name} at {first['first_flagged_utc']}" if first else ""
        window = [_f(r["max_window_rotation_deg"]) for r in g.rows]
        top = max((w for w in window if not math.isnan(w)), default=math.nan)
        label = g.rows[0].get("rig_label", "")
        lines.append(
            f"| [{g.name}](#{_slug(g.name).lower()}) | {label} | {len(g.rows)} | "
            f"{g.worst or 'not checked'} | {where} | {_fmt(top)} |"
        )
    lines.append("")
    if failed:
        lines += ["## Bags without an answer", "", "| bag | reason |", "|---|---|"]
        lines += [f"| {r['bag']} | {r['reason'].replace('|', '/')} |" for r in failed]
        lines.append("")
    for g in rigs:
        png = out / PLOTS / f"{_slug(g.name)}.png"
        plot_rig(g, png, thresholds)
        lines += [f'## <a id="{_slug(g.name).lower()}"></a>{g.name}', ""]
        lines += [f"![{g.name}]({PLOTS}/{png.name})", ""]
        lines += _bag_table(g) + [""]
    path = out / REPORT_MD
    path.write_text("\n".join(lines))
    return path
