"""Fill the matches cache for many image pairs, detecting each image once.

``MatchesCache`` computes matches pair by pair, so an image in k pairs is described k times per
SIFT ratio. This fills the same cache files (same key, same content: ``match_images`` is
``detect`` on both images then ``match_descriptors``) with one detection per image for all the
ratios, which makes the first run on ``../shared/data_lines`` (387 pairs over 103 images) several
times faster. Pairs already cached are skipped.

    python benchmarks/lines_prefetch.py [--ratios 0.75,0.95] [--manifest FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sepfm_ros.evaluation.manifest import PairSpec, load_manifest
from sepfm_ros.evaluation.matches_cache import (
    MatchSettings,
    cache_key,
    file_hash,
    read_image,
)
from sepfm_ros.pipeline import features
from sepfm_ros.pipeline.features import detect, make_detector, match_descriptors

REPO = Path(__file__).resolve().parent.parent
CACHE = REPO / ".cache" / "matches"


@contextlib.contextmanager
def _nearest_reused():
    """``match_descriptors`` reuses the last 2-NN search when it gets the same descriptor arrays
    again (the same pair at another ratio): the search is most of a pair's matching time, and
    the matches stay exactly ``match_descriptors``' own."""
    original = features._two_nearest
    last: dict = {}

    def two_nearest(desc_a, desc_b, kind):
        if (
            last.get("args") is None
            or any(x is not y for x, y in zip(last["args"], (desc_a, desc_b), strict=True))
            or last["kind"] != kind
        ):
            last.update(args=(desc_a, desc_b), kind=kind, value=original(desc_a, desc_b, kind))
        return last["value"]

    features._two_nearest = two_nearest
    try:
        yield
    finally:
        features._two_nearest = original


def prefetch(pairs: list[PairSpec], ratios: list[float], folder: Path = CACHE) -> int:
    """Write the missing cache files of ``pairs`` x ``ratios`` (SIFT); returns how many."""
    folder.mkdir(parents=True, exist_ok=True)
    hashes: dict[Path, str] = {}
    todo = []  # (pair, settings, path)
    for pair in pairs:
        if pair.img_a is None or pair.img_b is None:
            continue
        for p in (pair.img_a, pair.img_b):
            if p not in hashes:
                hashes[p] = file_hash(p)
        for ratio in ratios:
            s = MatchSettings("sift", ratio)
            path = folder / f"{cache_key(hashes[pair.img_a], hashes[pair.img_b], s)}.npz"
            if not path.is_file():
                todo.append((pair, s, path))
    if not todo:
        return 0
    # images in the order they are first needed; features kept until their last use
    last_use: dict[Path, int] = {}
    for i, (pair, _, _) in enumerate(todo):
        last_use[pair.img_a] = last_use[pair.img_b] = i
    feats: dict[Path, tuple] = {}
    detector = make_detector("sift", MatchSettings("sift").detector_cap())
    t0 = time.time()
    with _nearest_reused():
        for i, (pair, s, path) in enumerate(todo):
            for p in (pair.img_a, pair.img_b):
                if p not in feats:
                    img = read_image(p)
                    feats[p] = (*detect(img, detector), (int(img.shape[1]), int(img.shape[0])))
            pa, da, size_a = feats[pair.img_a]
            pb, db, size_b = feats[pair.img_b]
            m = match_descriptors(pa, da, pb, db, features="sift", ratio=s.ratio)
            fd, tmp = tempfile.mkstemp(suffix=".npz", dir=folder)
            with os.fdopen(fd, "wb") as f:
                np.savez(
                    f,
                    pts_a=m.pts_a,
                    pts_b=m.pts_b,
                    ratio=m.ratio,
                    size_a=np.array(size_a),
                    size_b=np.array(size_b),
                )
            os.replace(tmp, path)
            for p in (pair.img_a, pair.img_b):
                if last_use[p] == i:
                    feats.pop(p, None)
            sys.stderr.write(f"\r  matches: {i + 1}/{len(todo)} cached, {time.time() - t0:.0f} s")
    sys.stderr.write("\n")
    return len(todo)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--manifest", type=Path, default=REPO.parent / "shared" / "data_lines" / "pairs.json"
    )
    ap.add_argument("--ratios", default="0.75,0.95")
    a = ap.parse_args(argv)
    pairs, _ = load_manifest(a.manifest)
    n = prefetch(pairs, [float(r) for r in a.ratios.split(",")])
    print(f"{n} cache files written", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
