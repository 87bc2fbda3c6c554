"""Markers for whole test modules, applied by each test folder's conftest."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pytest


def mark_modules(
    items: list[pytest.Item],
    folder: Path,
    marks: Mapping[str, tuple[str, ...]],
    recursive: bool = True,
) -> None:
    """Add ``marks[module]`` (marker names, e.g. ("slow", "timing")) to every collected test of
    a module named in ``marks`` that lives in ``folder`` (or below it, with ``recursive``)."""
    folder = folder.resolve()
    for item in items:
        path = Path(str(item.path)).resolve()
        inside = folder in path.parents if recursive else path.parent == folder
        if not inside:
            continue
        for mark in marks.get(path.stem, ()):
            item.add_marker(getattr(pytest.mark, mark))
