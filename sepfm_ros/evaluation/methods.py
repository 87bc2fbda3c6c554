"""The one registry of estimators the evaluation compares.

- Ours, from :mod:`sepfm_ros.geometry` (its ``METHODS``): ``sep4``, ``sep5``, ``sep4-lmeds``,
  ``sep5-lmeds`` (the separable two-stage estimator) and the package's own baselines ``ransac7``,
  ``ransac8``, ``lmeds7``, ``lmeds8`` (least median of squares, seven- / eight-point; the
  ``-lmeds`` variants are least median of squares too).
- OpenCV ``cv2.findFundamentalMat``: ``cv-ransac`` (FM_RANSAC), ``cv-lmeds`` (FM_LMEDS),
  ``cv-magsac`` (USAC_MAGSAC), ``cv-accurate`` (USAC_ACCURATE), OpenCV's defaults otherwise
  (maxIters 1000). OpenCV's samplers start from a fixed internal random state, so a seed is
  applied as a seeded permutation of the input matches (undone on the result); OpenCV exposes no
  hypothesis count (reported n/a).
- PoseLib ``poselib.estimate_fundamental`` (``poselib``), when the optional ``poselib`` extra is
  installed: its LO-RANSAC with bundle refinement, ``max_epipolar_error`` = threshold,
  ``success_prob`` = confidence, ``seed`` = seed, other options at PoseLib's defaults; its RANSAC
  iterations are reported as hypotheses (samples drawn).
- SupeRANSAC ``pysuperansac.estimateFundamentalMatrix`` (Barath et al. 2025), when the optional
  ``superansac`` extra is installed (``pysuperansac`` ships a CPython 3.11 wheel only), twice:
  ``superansac`` at its defaults (MAGSAC++ scoring, PROSAC sampling, nested-RANSAC local and
  iterated least-squares final optimisation, ``min_iterations`` 1000, ``max_iterations`` 5000)
  and ``superansac-adaptive``, the same with ``min_iterations`` 1, so that its adaptive RANSAC
  stopping alone decides, as it does for the other methods. Its ``inlier_threshold`` is a Sampson
  distance in pixels; a match whose two point-line distances are both d has symmetric epipolar
  distance d and Sampson distance d / sqrt(2), so it gets ``threshold / sqrt(2)``.
  ``confidence`` = confidence; the matches go in the order given (best first, PROSAC's order).
  It takes no seed (its own generator is seeded inside), so the seed is not used. Its returned
  iterations are reported as hypotheses.

Every method gets the same matches, threshold (px) and confidence, and is timed the same way.
"""

from __future__ import annotations

import importlib.util
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from sepfm_ros.geometry import METHODS as GEOMETRY_METHODS
from sepfm_ros.geometry import estimate_fundamental, normalize_fundamental


@dataclass
class MethodResult:
    """One estimator run.

    Attributes:
        F: (3, 3) estimate (unit norm) or None.
        own_inliers: how many matches the method itself marked inlier.
        hypotheses, stage1_hypotheses, stage2_hypotheses: counts, or None where the method does
            not expose them.
        ms: wall-clock milliseconds of the call.
        status: "ok" or the method's reason for no/unreliable model.
        line_pair: ((a, b, c), (a, b, c)) line pair used by the separable methods, else None.
        line_inliers: (M,) int indices of matches on the line pair agreeing with H_e.
        fallback: the separable method fell back to plain RANSAC (no usable line pair).
        line_search_skipped: the separable method skipped its line search (the escape: plain
            RANSAC was the cheaper way at the inlier rate its first samples showed).
        H_e, control_points: the separable method's stage-1 line homography and the control
            points of its line pair (None otherwise).
    """

    F: np.ndarray | None
    own_inliers: int
    hypotheses: int | None
    stage1_hypotheses: int | None
    stage2_hypotheses: int | None
    ms: float
    status: str = "ok"
    line_pair: tuple | None = None
    line_inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    fallback: bool = False
    line_search_skipped: bool = False
    H_e: np.ndarray | None = None
    control_points: tuple[np.ndarray, np.ndarray] | None = None


#: run(pts_a (N,2), pts_b (N,2), size_a (w,h), size_b (w,h), threshold px, confidence, seed)
Runner = Callable[
    [np.ndarray, np.ndarray, tuple[int, int], tuple[int, int], float, float, int], MethodResult
]


@dataclass(frozen=True)
class Method:
    """A registered estimator: ``name`` as in the report, ``family`` ("ours", "opencv",
    "poselib", "superansac"), whether it is one of the paper's separable methods, and how to
    run it."""

    name: str
    family: str
    description: str
    run: Runner
    separable: bool = False


def _ours(name: str) -> Runner:
    def run(pts_a, pts_b, size_a, size_b, threshold, confidence, seed) -> MethodResult:
        t0 = time.perf_counter()
        est = estimate_fundamental(
            pts_a,
            pts_b,
            size_a,
            size_b,
            method=name,
            threshold=threshold,
            confidence=confidence,
            seed=seed,
        )
        ms = (time.perf_counter() - t0) * 1e3
        return MethodResult(
            F=None if est.F is None else normalize_fundamental(est.F),
            own_inliers=est.num_inliers,
            hypotheses=int(est.hypotheses),
            stage1_hypotheses=int(est.stage1_hypotheses),
            stage2_hypotheses=int(est.stage2_hypotheses),
            ms=ms,
            status=est.status,
            line_pair=est.line_pair,
            line_inliers=np.asarray(est.line_inliers, dtype=np.int64),
            fallback=bool(est.fallback),
            line_search_skipped=bool(est.line_search_skipped),
            H_e=est.H_e,
            control_points=est.control_points,
        )

    return run


def _opencv(flag: int) -> Runner:
    def run(pts_a, pts_b, size_a, size_b, threshold, confidence, seed) -> MethodResult:
        n = pts_a.shape[0]
        perm = np.random.default_rng(seed).permutation(n)
        t0 = time.perf_counter()
        F, mask = cv2.findFundamentalMat(
            np.ascontiguousarray(pts_a[perm]),
            np.ascontiguousarray(pts_b[perm]),
            flag,
            float(threshold),
            float(confidence),
        )
        ms = (time.perf_counter() - t0) * 1e3
        if F is None or F.shape[0] < 3 or not np.all(np.isfinite(F)):
            return MethodResult(None, 0, None, None, None, ms, status="no model")
        own = int(np.count_nonzero(mask)) if mask is not None else 0
        return MethodResult(normalize_fundamental(F[:3]), own, None, None, None, ms)

    return run


def _poselib(pts_a, pts_b, size_a, size_b, threshold, confidence, seed) -> MethodResult:
    import poselib

    opts = {"max_epipolar_error": float(threshold), "success_prob": float(confidence)}
    opts["seed"] = int(seed)
    t0 = time.perf_counter()
    F, info = poselib.estimate_fundamental(pts_a, pts_b, opts, {})
    ms = (time.perf_counter() - t0) * 1e3
    F = np.asarray(F, dtype=np.float64)
    iters = int(info.get("iterations", 0))
    if not np.all(np.isfinite(F)) or np.linalg.norm(F) == 0 or info.get("num_inliers", 0) == 0:
        return MethodResult(None, 0, iters, None, None, ms, status="no model")
    own = int(np.count_nonzero(info.get("inliers", [])))
    return MethodResult(normalize_fundamental(F), own, iters, None, None, ms)


def poselib_available() -> bool:
    """True when the optional PoseLib package can be imported."""
    return importlib.util.find_spec("poselib") is not None


#: SupeRANSAC's min_iterations for ``superansac-adaptive`` (its default is 1000): 1 leaves the
#: stop to its adaptive RANSAC criterion at the run's confidence.
SUPERANSAC_ADAPTIVE_MIN_ITERATIONS = 1


def _superansac(min_iterations: int | None) -> Runner:
    """Runner of ``pysuperansac.estimateFundamentalMatrix``; ``min_iterations`` None keeps its
    default (1000)."""

    def run(pts_a, pts_b, size_a, size_b, threshold, confidence, seed) -> MethodResult:
        import pysuperansac

        # a fresh settings object per call: the call rescales inlier_threshold in place
        settings = pysuperansac.RANSACSettings()
        settings.inlier_threshold = float(threshold) / math.sqrt(2.0)  # symmetric px -> Sampson
        settings.confidence = float(confidence)
        if min_iterations is not None:
            settings.min_iterations = int(min_iterations)
        corr = np.ascontiguousarray(np.hstack([pts_a, pts_b]), dtype=np.float64)
        sizes = [float(size_a[0]), float(size_a[1]), float(size_b[0]), float(size_b[1])]
        t0 = time.perf_counter()
        F, inliers, _score, iters = pysuperansac.estimateFundamentalMatrix(
            corr, sizes, [], settings
        )
        ms = (time.perf_counter() - t0) * 1e3
        F = np.asarray(F, dtype=np.float64)
        if F.shape != (3, 3) or not np.all(np.isfinite(F)) or np.linalg.norm(F) == 0:
            return MethodResult(None, 0, int(iters), None, None, ms, status="no model")
        return MethodResult(normalize_fundamental(F), len(inliers), int(iters), None, None, ms)

    return run


def superansac_available() -> bool:
    """True when the optional SupeRANSAC package (``pysuperansac``) can be imported."""
    return importlib.util.find_spec("pysuperansac") is not None


def superansac_methods() -> list[str]:
    """The SupeRANSAC methods when ``pysuperansac`` is installed, else none (for benchmarks)."""
    return ["superansac", "superansac-adaptive"] if superansac_available() else []


#: family -> (whether it is installed, what the error says to install)
_OPTIONAL: dict[str, tuple[Callable[[], bool], str]] = {
    "poselib": (poselib_available, "PoseLib: pip install 'sepfm_ros[poselib]'"),
    "superansac": (
        superansac_available,
        "SupeRANSAC: pip install 'sepfm_ros[superansac]' (pysuperansac has a wheel for "
        "CPython 3.11 on x86_64 Linux only)",
    ),
}


def _usable(name: str) -> bool:
    """True when method ``name``'s optional package, if it needs one, is installed."""
    family = REGISTRY[name].family
    return family not in _OPTIONAL or _OPTIONAL[family][0]()


def _registry() -> dict[str, Method]:
    reg: dict[str, Method] = {}
    for name in GEOMETRY_METHODS:
        sep = name.startswith("sep")
        desc = (
            f"separable two-stage estimator ({name})"
            if sep
            else f"sepfm_ros.geometry baseline ({name})"
        )
        reg[name] = Method(name, "ours", desc, _ours(name), separable=sep)
    for name, flag, desc in (
        ("cv-ransac", cv2.FM_RANSAC, "cv2.findFundamentalMat FM_RANSAC"),
        ("cv-lmeds", cv2.FM_LMEDS, "cv2.findFundamentalMat FM_LMEDS"),
        ("cv-magsac", cv2.USAC_MAGSAC, "cv2.findFundamentalMat USAC_MAGSAC"),
        ("cv-accurate", cv2.USAC_ACCURATE, "cv2.findFundamentalMat USAC_ACCURATE"),
    ):
        reg[name] = Method(name, "opencv", desc, _opencv(flag))
    desc = "poselib.estimate_fundamental (LO-RANSAC + refinement; PoseLib's min_iterations 1000)"
    reg["poselib"] = Method("poselib", "poselib", desc, _poselib)
    desc = "pysuperansac.estimateFundamentalMatrix at its defaults (min_iterations 1000)"
    reg["superansac"] = Method("superansac", "superansac", desc, _superansac(None))
    desc = (
        "pysuperansac.estimateFundamentalMatrix, adaptive stopping below 1000 iterations "
        f"(min_iterations {SUPERANSAC_ADAPTIVE_MIN_ITERATIONS})"
    )
    adaptive = _superansac(SUPERANSAC_ADAPTIVE_MIN_ITERATIONS)
    reg["superansac-adaptive"] = Method("superansac-adaptive", "superansac", desc, adaptive)
    return reg


#: Every method the evaluation knows, by report name.
REGISTRY: dict[str, Method] = _registry()


def available_methods() -> list[str]:
    """Names of the registered methods usable here (PoseLib and SupeRANSAC only when
    installed)."""
    return [n for n in REGISTRY if _usable(n)]


def resolve_methods(spec: str) -> list[Method]:
    """Methods from a comma list of names, or ``all`` (every available method), ``ours``,
    ``opencv``. Raises ValueError naming unknown or unavailable methods."""
    names: list[str] = []
    for token in (t.strip() for t in spec.split(",")):
        if not token:
            continue
        if token == "all":
            names += available_methods()
        elif token in ("ours", "opencv"):
            names += [n for n in available_methods() if REGISTRY[n].family == token]
        elif token in REGISTRY:
            if not _usable(token):
                needs = _OPTIONAL[REGISTRY[token].family][1]
                raise ValueError(f"method {token!r} needs {needs}")
            names.append(token)
        else:
            raise ValueError(
                f"unknown method {token!r}; known: all, ours, opencv, {list(REGISTRY)}"
            )
    unique = list(dict.fromkeys(names))
    if not unique:
        raise ValueError("no method selected")
    return [REGISTRY[n] for n in unique]
