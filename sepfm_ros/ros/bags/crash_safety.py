"""Crash-safety helpers of the bag writer: atomic files, directory fsync, stale scratch folders.

A file replaced with :func:`write_atomic` is always either the old or the new content, even when
the process is killed mid-write; :func:`remove_stale_scratch` removes the hidden folders that a
writer killed before its bag got its name leaves behind.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from ruamel.yaml import YAML


def safe_yaml() -> YAML:
    """A YAML dumper/loader in safe mode, block style (as rosbag2 writes metadata.yaml)."""
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    return yaml


def write_atomic(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` via a synced temporary file and a rename."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def fsync_dir(path: Path) -> None:
    """fsync a directory (so renames in it are durable); errors are ignored."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def remove_stale_scratch(final: Path) -> list[Path]:
    """Remove the hidden ``.NAME.creating-<pid>-*`` siblings of ``final`` whose process is gone.

    Such a folder is what a writer killed in its first milliseconds leaves (before the bag got
    its name, so before anything was written to it). Folders of live processes are kept.
    Returns the removed paths.
    """
    removed = []
    prefix = f".{final.name}.creating-"
    if not final.parent.is_dir():
        return removed
    for entry in final.parent.iterdir():
        if not entry.name.startswith(prefix) or not entry.is_dir():
            continue
        pid_text = entry.name[len(prefix) :].split("-", 1)[0]
        if pid_text.isdigit() and not _pid_alive(int(pid_text)):
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
    return removed
