"""The files a camera driver loads after ``calibration_check --write-corrected``: the corrected
rig's ``left.yaml`` and ``right.yaml`` (``camera_calibration_parsers`` YAML, what
``camera_info_manager`` loads from ``camera_info_url``) and ``correction.json`` beside them.

The camera files hold the camera_info of the corrected rig
(:func:`~sepfm_ros.geometry.calibrated.stereo_rectify.corrected_models`): K and D as the bag's
camera_info has them, R and P of a new rectification from the corrected extrinsics with the
input's baseline and P conventions. For rectified input (``image_rect``) they describe the
rectified images as the raw images of a camera with K = the old P[:, :3] and no distortion, so
that rectifying them again with these files gives images rectified with the corrected
calibration.

``correction.json`` says what was found, for people and scripts alike: ``corrected`` (true or
false), ``reason`` (the correction's one-line account, or why there is none), the input (bag,
topics, raw or rectified images, pairs checked, the final decision) and, with a correction,
the rotation of camera b (the right camera) about its optical axes (pitch x, yaw y, roll z,
degrees), the half-widths of their 95 % intervals, whether yaw was determined (else it is the
calibration's), the pairs and matches used, and the corrected R and t (``X_b = R X_a + t``,
metres). JSON rather than YAML: every language reads it with its standard library, and no YAML
1.1/1.2 difference can turn a number into a string.

Without a correction no camera file is written; camera files an earlier run wrote into the
same folder (listed by its ``correction.json``) are removed, so the folder never holds files
that the latest check does not stand behind.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sepfm_ros.ros.msgs.camera_yaml import camera_name, write_camera_yaml
from sepfm_ros.ros.offline.rig_check import CheckRun

CORRECTION_JSON = "correction.json"
CAMERA_FILES = ("left.yaml", "right.yaml")
AXES = ("pitch", "yaw", "roll")


def _names(run: CheckRun) -> tuple[str, str]:
    """The cameras' names: their camera_info frame ids, else their image topics."""
    left, right = (camera_name(f or t) for f, t in zip(run.frames, run.topics, strict=True))
    return left, right


def correction_summary(run: CheckRun, bag: str, files: list[str]) -> dict[str, Any]:
    """What ``correction.json`` holds for ``run`` (``files``: the camera files written)."""
    result = run.correction
    last = run.rows[-1].status.level_name if run.rows else ""
    summary: dict[str, Any] = {
        "corrected": bool(files),
        "reason": result.reason if result is not None else "no pair was checked",
        "bag": bag,
        "topics": {
            "left": run.topics[0],
            "right": run.topics[1],
            "left_info": run.info_topics[0],
            "right_info": run.info_topics[1],
        },
        "images": "rectified" if run.rectified else "raw",
        "pairs_checked": len(run.rows),
        "final_level": last,
        "files": files,
    }
    fix = result.correction if result is not None else None
    if fix is not None and files:
        summary["correction"] = {
            "axes": "camera b (right) optical frame: x right (pitch), y down (yaw), z forward"
            " (roll)",
            "rotation_deg": dict(zip(AXES, map(float, fix.axes_deg), strict=True)),
            "interval95_deg": dict(zip(AXES, map(float, fix.interval_deg), strict=True)),
            "yaw_determined": bool(fix.yaw_determined),
            "yaw_estimate_deg": float(fix.yaw_estimate_deg),
            "pairs": int(fix.n_pairs),
            "matches": int(fix.n_matches),
            "R": fix.R.tolist(),
            "t_m": fix.t.tolist(),
        }
    return summary


def _remove_earlier(out: Path) -> list[Path]:
    """Remove the camera files an earlier run listed in ``out``'s correction.json."""
    removed = []
    try:
        earlier = json.loads((out / CORRECTION_JSON).read_text()).get("files", [])
    except (OSError, ValueError, AttributeError):
        return removed
    for name in earlier:
        path = out / str(name)
        if str(name) in CAMERA_FILES and path.is_file():
            path.unlink()
            removed.append(path)
    return removed


def write_corrected(run: CheckRun, out: Path, bag: str) -> tuple[list[Path], str]:
    """Write the corrected camera files and ``correction.json`` into ``out`` (created).

    Returns:
        (paths written, one line for the user: what was written, or why no camera file).
    """
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if run.corrected is not None:
        for path, model, name in zip(
            (out / f for f in CAMERA_FILES), run.corrected, _names(run), strict=True
        ):
            write_camera_yaml(path, model, name)
            written.append(path)
        line = f"corrected calibration: {run.correction.reason if run.correction else ''}"
    else:
        removed = _remove_earlier(out)
        reason = run.correction.reason if run.correction is not None else "no pair was checked"
        line = f"no corrected calibration written: {reason}"
        if removed:
            line += f" (removed the earlier run's {', '.join(p.name for p in removed)})"
    summary = correction_summary(run, bag, [p.name for p in written])
    path = out / CORRECTION_JSON
    path.write_text(json.dumps(summary, indent=2) + "\n")
    return [*written, path], line
