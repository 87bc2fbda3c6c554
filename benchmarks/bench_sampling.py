"""Benchmark: PROSAC / SPRT / bail-out of the shared RANSAC loop on and off, real matches.

Every pair of the manifest (up to ``--max-pairs``), SIFT matches at ``--ratio`` in the matcher's
order (best Lowe ratio first, which PROSAC uses), each of ours with each sampling configuration
and OpenCV's MAGSAC / USAC_ACCURATE side by side (OpenCV gets the matches shuffled, as in the
evaluation). Printed: success (median GT-positive error < 1 px and enough positives recovered),
mean F-score against the GT positives, median hypotheses, median ms.

    python benchmarks/bench_sampling.py [--max-pairs 60] [--ratio 0.95] [--outliers 0]

``--outliers R`` appends random wrong matches (as bench_outliers.py) up to outlier rate R, at the
end of the order (the worst matches last, as a ratio-sorted list would have them).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from sepfm_ros.evaluation.manifest import load_manifest
from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings
from sepfm_ros.evaluation.metrics import positives, run_metrics
from sepfm_ros.geometry import estimate_fundamental

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
CONFIGS = {
    "off": {},
    "prosac": {"prosac": True},
    "sprt": {"sprt": True},
    "bailout": {"bailout": True},
    "all": {"prosac": True, "sprt": True, "bailout": True},
}
CV = {"cv-magsac": cv2.USAC_MAGSAC, "cv-accurate": cv2.USAC_ACCURATE}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--max-pairs", type=int, default=60)
    ap.add_argument("--ratio", type=float, default=0.95)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--methods", default="sep4,sep5,ransac7")
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--outliers", type=float, default=0.0)
    ap.add_argument("--cache", default=str(REPO / ".cache" / "eval_matches"))
    a = ap.parse_args(argv)
    pairs, _ = load_manifest(DATA / "pairs.json")
    pairs = pairs[: a.max_pairs]
    cache = MatchesCache(a.cache, MatchSettings("sift", a.ratio))
    methods = a.methods.split(",")
    configs = a.configs.split(",")
    rows: dict[tuple[str, str], list] = {}
    rng = np.random.default_rng(a.seed)
    t0 = time.time()
    for i, pair in enumerate(pairs):
        m = cache.matches(pair)
        pa, pb = m.pts_a, m.pts_b
        if len(pa) < 8:
            continue
        if a.outliers > 0:
            pos0 = positives(pair.F_gt, pa, pb)
            extra = max(0, int(np.ceil(pos0.sum() / (1.0 - a.outliers))) - len(pa))
            ia, ib = rng.integers(0, len(pa), extra), rng.integers(0, len(pb), extra)
            pa = np.concatenate([pa, pa[ia] + rng.normal(0.0, 0.3, (extra, 2))])
            pb = np.concatenate([pb, pb[ib]])
        pos = positives(pair.F_gt, pa, pb)
        for name in methods:
            for cfg in configs:
                t = time.perf_counter()
                try:
                    e = estimate_fundamental(
                        pa, pb, m.size_a, m.size_b, method=name, seed=a.seed, **CONFIGS[cfg]
                    )
                    F, hyp = e.F, e.hypotheses
                except ValueError:
                    F, hyp = None, 0
                ms = (time.perf_counter() - t) * 1e3
                met = run_metrics(F, pa, pb, pos, 1.0)
                ok = met.succeeded
                rows.setdefault((name, cfg), []).append((ok, met.f_score, hyp, ms))
        perm = np.random.default_rng(a.seed).permutation(len(pa))
        for name, flag in CV.items():
            t = time.perf_counter()
            F, _ = cv2.findFundamentalMat(
                np.ascontiguousarray(pa[perm]), np.ascontiguousarray(pb[perm]), flag, 1.0, 0.99
            )
            ms = (time.perf_counter() - t) * 1e3
            F = F[:3] if F is not None and F.shape[0] >= 3 and np.all(np.isfinite(F)) else None
            met = run_metrics(F, pa, pb, pos, 1.0)
            ok = met.succeeded
            rows.setdefault((name, "-"), []).append((ok, met.f_score, np.nan, ms))
        sys.stderr.write(f"\r  {i + 1}/{len(pairs)} pairs, {time.time() - t0:.0f} s")
    sys.stderr.write("\n")
    print(f"{len(pairs)} pairs, SIFT {a.ratio}, extra outliers to {a.outliers}, seed {a.seed}")
    print("| method | sampling | success % | F-score | hypotheses (median) | ms (median) |")
    print("|---|---|---|---|---|---|")
    for (name, cfg), r in rows.items():
        r = np.array(r, dtype=float)
        hyp = "-" if np.isnan(r[:, 2]).all() else f"{np.median(r[:, 2]):.0f}"
        print(
            f"| {name} | {cfg} | {100 * r[:, 0].mean():.1f} | {np.nanmean(r[:, 1]):.3f} | "
            f"{hyp} | {np.median(r[:, 3]):.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
