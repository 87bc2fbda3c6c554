#!/usr/bin/env python3
"""Rebuild the committed bags under ``bags/`` from the package's own renderer.

    python scripts/make_bundled_bags.py [--force]

Each bag is a synthetic "street" scene (textured planes with straight edges, known cameras, so the
ground-truth F is exact) at 2 frames per second (a rate the node keeps up with on busy 2-core
machines while the demo also records its debug image), zstd-compressed mcap chunks:

- ``bags/synthetic_stereo``: 12 stereo frames, mono8, ``/left/image_raw`` + ``/right/image_raw``
  with ``/left/camera_info`` + ``/right/camera_info`` (a converged rig: R and P rectifying);
- ``bags/synthetic_motion``: 13 frames (12 pairs), PNG ``/image_raw/compressed`` (the node's
  ``transport:=compressed``) with ``/camera_info``.

All carry ``/ground_truth/fundamental``. The output is deterministic (fixed seeds and stamps).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from sepfm_ros.ros.bags.synthesis import make_bag, synthetic_frames

RATE_HZ = 2.0
BAGS = Path(__file__).resolve().parent.parent / "bags"

# name -> (kind, frames, encoding)
SPECS = {
    "synthetic_stereo": ("stereo", 12, "mono8"),
    "synthetic_motion": ("motion", 13, "compressed"),
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--force", action="store_true", help="replace existing bags")
    parser.add_argument("--out", type=Path, default=BAGS, help="output folder (default bags/)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name, (kind, n_frames, encoding) in SPECS.items():
        out = args.out / name
        if out.exists():
            if not args.force:
                print(f"{out} exists (use --force to rebuild)")
                continue
            shutil.rmtree(out)
        mode, frames = synthetic_frames(kind, n_frames, seed=0)
        n = make_bag(out, mode, frames, rate_hz=RATE_HZ, encoding=encoding, compress=True)
        size = sum(p.stat().st_size for p in out.iterdir())
        print(f"{out}: {mode}, {len(frames)} frames, {n} messages, {size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
