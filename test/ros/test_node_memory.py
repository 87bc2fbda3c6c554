"""The node's malloc settings (sepfm_ros/ros/memory.py): where they apply. Their effect on a
live node is measured by the fuzz tests in test_robustness_live.py; the DDS settings are
tested in test_dds.py."""

from __future__ import annotations

import ctypes.util
import platform
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_malloc_settings_apply_on_glibc_and_are_harmless_elsewhere():
    # process-wide settings: in a child process, so the test process's allocator stays as is
    on_glibc = platform.libc_ver()[0] == "glibc" and ctypes.util.find_library("c") is not None
    code = (
        "from sepfm_ros.ros.node import memory\n"
        "print(memory.configure_malloc())\n"
        "memory.release_free_memory()\n"  # no-op without glibc; must not raise either way
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(on_glibc)
