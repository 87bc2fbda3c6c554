"""Which rig a bag belongs to.

Bags carry no robot id. By default a rig is what the data says: the input topics and each
camera's frame id, image size and calibration (K, D, P of its camera_info), so the same robot's
bags group together across folders, and a robot that was recalibrated starts a new rig (its
calibration is what the audit checks against). ``--rig-from PATTERN`` names rigs by a regular
expression on the bag's path instead (its ``rig`` group, else its first group, else the whole
match); the audit then says when one name covers bags of different data identities.
"""

from __future__ import annotations

import hashlib
import re
from collections import defaultdict
from collections.abc import Iterable

from sepfm_ros.fleet.records import BagInfo


class RigPatternError(ValueError):
    """A ``--rig-from`` pattern that is not a valid regular expression."""


def _numbers(values: tuple[float, ...]) -> str:
    return ",".join(f"{v:.9g}" for v in values)


def rig_identity(info: BagInfo) -> tuple[str, str]:
    """(rig id, label) from what the bag says: ``rig-<12 hex>`` over mode, topics, frame ids,
    sizes and K, D, P; the label joins the frame ids (or topics) for people."""
    h = hashlib.sha256(info.mode.encode())
    for cam in info.cameras:
        h.update(
            f"|{cam.topic}|{cam.frame_id}|{cam.size}|{_numbers(cam.K)}|{_numbers(cam.D)}|"
            f"{_numbers(cam.P)}".encode()
        )
    names = [c.frame_id or c.topic for c in info.cameras] or list(info.topics)
    return f"rig-{h.hexdigest()[:12]}", " + ".join(names)


def compile_pattern(pattern: str | None) -> re.Pattern[str] | None:
    """The ``--rig-from`` regular expression (RigPatternError when invalid)."""
    if pattern is None:
        return None
    try:
        return re.compile(pattern)
    except re.error as err:
        raise RigPatternError(
            f"--rig-from {pattern!r} is not a regular expression: {err}"
        ) from None


def rig_name(pattern: re.Pattern[str] | None, bag: str, rig_id: str) -> str:
    """The rig's display name: from the bag path by ``pattern`` when it matches, else the id."""
    if pattern is None:
        return rig_id
    m = pattern.search(bag)
    if m is None:
        return rig_id
    if "rig" in pattern.groupindex:
        return m.group("rig") or rig_id
    return (m.group(1) if pattern.groups else m.group(0)) or rig_id


def naming_conflicts(rows: Iterable[tuple[str, str, str]]) -> list[str]:
    """Warnings for (rig name, rig id, bag) rows: one name over several data identities (a
    path pattern that groups different rigs or calibrations), or one identity under several
    names (a rig whose bags sit in differently named folders)."""
    ids_of: dict[str, set[str]] = defaultdict(set)
    names_of: dict[str, set[str]] = defaultdict(set)
    for name, rig_id, _ in rows:
        if name != rig_id and not rig_id.startswith("unknown"):
            ids_of[name].add(rig_id)
            names_of[rig_id].add(name)
    out = []
    for name, ids in sorted(ids_of.items()):
        if len(ids) > 1:
            out.append(
                f"rig {name} (named from the bag paths) holds bags of {len(ids)} different "
                f"cameras or calibrations ({', '.join(sorted(ids))}): the path pattern may group "
                "different rigs, or the rig was recalibrated"
            )
    for rig_id, names in sorted(names_of.items()):
        if len(names) > 1:
            out.append(
                f"the same cameras and calibration ({rig_id}) appear under {len(names)} rig "
                f"names from the paths: {', '.join(sorted(names))}"
            )
    return out
