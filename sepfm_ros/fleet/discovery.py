"""Which bags an audit covers: directories (searched recursively), glob patterns, text files
listing bags, and bags named directly, in rosbag2 (a folder with ``metadata.yaml``, or a bare
``.mcap``/``.db3``) or ROS 1 (``.bag``) form.
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass, field
from pathlib import Path

BAG_SUFFIXES = (".mcap", ".db3", ".bag")
LIST_SUFFIXES = (".txt", ".list")
_GLOB_CHARS = set("*?[")


@dataclass
class Discovery:
    """The bags found (resolved, sorted, each once) and what was given but held none."""

    bags: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _is_rosbag2_dir(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def _bags_under(folder: Path) -> list[Path]:
    """Bags inside ``folder``: rosbag2 folders (not searched further) and bag files."""
    found = []
    for root, dirs, files in os.walk(folder):
        here = Path(root)
        if (here / "metadata.yaml").is_file():
            found.append(here)
            dirs.clear()  # a rosbag2 folder's storage files are not bags of their own
            continue
        dirs.sort()
        found += [here / f for f in sorted(files) if f.endswith(BAG_SUFFIXES)]
    return found


def _expand(item: str, base: Path, out: Discovery, depth: int = 0) -> list[Path]:
    """The bags one command-line item (or list line) stands for."""
    if _GLOB_CHARS & set(item):
        pattern = item if os.path.isabs(item) else str(base / item)
        matches = sorted(glob.glob(pattern, recursive=True))
        if not matches:
            out.notes.append(f"{item}: no file matches this pattern")
        paths: list[Path] = []
        for m in matches:
            paths += _expand(m, base, out, depth)
        return paths
    path = Path(item) if os.path.isabs(item) else base / item
    if path.is_file() and path.suffix in LIST_SUFFIXES:
        if depth > 4:
            out.notes.append(f"{item}: bag lists nested too deep, not read")
            return []
        paths = []
        for line in path.read_text().splitlines():
            line = line.strip()
            if line and not line.startswith("#"):
                paths += _expand(line, path.parent, out, depth + 1)
        return paths
    if path.is_dir() and not _is_rosbag2_dir(path):
        found = _bags_under(path)
        if not found:
            out.notes.append(f"{item}: no bag in this folder")
        return found
    # a bag, or a path that is not one: the audit gives it a row saying why
    return [path]


def find_bags(items: list[str], base: Path | None = None) -> Discovery:
    """The bags that ``items`` (command-line arguments) name, resolved and sorted, each once.

    An item is a bag, a folder (every bag under it), a glob pattern (``**`` recurses) or a text
    file (``.txt``/``.list``) with one item per line (``#`` comments; relative to the list's
    folder). A named path that does not exist or is not a bag is kept: its row says why.
    """
    base = base or Path.cwd()
    out = Discovery()
    seen: set[Path] = set()
    for item in items:
        for path in _expand(item, base, out):
            resolved = path.resolve()
            if resolved not in seen:
                seen.add(resolved)
                out.bags.append(resolved)
    out.bags.sort()
    return out


def bag_fingerprint(path: Path) -> tuple[int, int]:
    """(total bytes, newest mtime ns) of a bag's files: a bag recorded anew is a new bag."""
    files = [p for p in path.rglob("*") if p.is_file()] if path.is_dir() else [path]
    size, mtime = 0, 0
    for f in files:
        try:
            st = f.stat()
        except OSError:
            continue
        size += st.st_size
        mtime = max(mtime, st.st_mtime_ns)
    return size, mtime
