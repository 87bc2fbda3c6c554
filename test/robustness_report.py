"""Figures of the robustness tests: printed at the end of each test module and, when the
environment variable ``SEPFM_ROBUSTNESS_REPORT`` names a JSON file, merged into it (that is how
``benchmarks/bench_robustness.py`` collects them into its report).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

REPORT_ENV = "SEPFM_ROBUSTNESS_REPORT"


class Figures:
    """section -> {name: value}; ``add`` records one figure and prints it at once."""

    def __init__(self) -> None:
        self.sections: dict[str, dict[str, Any]] = {}

    def add(self, section: str, **values: Any) -> None:
        self.sections.setdefault(section, {}).update(values)
        text = ", ".join(f"{k}={_fmt(v)}" for k, v in values.items())
        print(f"\n[robustness] {section}: {text}", flush=True)

    def write(self) -> None:
        target = os.environ.get(REPORT_ENV)
        if not target or not self.sections:
            return
        path = Path(target)
        old = json.loads(path.read_text()) if path.is_file() else {}
        for section, values in self.sections.items():
            old.setdefault(section, {}).update(values)
        path.write_text(json.dumps(old, indent=2, sort_keys=True, default=str) + "\n")


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)
