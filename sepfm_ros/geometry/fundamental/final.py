"""The final model of an estimate and its status: inner sampling, refits on all inliers,
Sampson refinement, the plane-and-parallax check (with the period-shifted plane copy), the
Levenberg-Marquardt polish, the inlier mask and the status (degenerate, unreliable, not
significant, or ok); the LMedS methods' final model by median and robust scale."""

from __future__ import annotations

import time

import numpy as np

from sepfm_ros.geometry.epipolar import msac_kernel, normalize_fundamental
from sepfm_ros.geometry.estimate import Estimate, StatusCode
from sepfm_ros.geometry.fundamental.checks import line_band_status
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.degeneracy import (
    PLANE_TOLERANCE,
    PlaneCheck,
    plane_and_parallax,
    transfer_error,
)
from sepfm_ros.geometry.fundamental.inner_sampling import inner_sampling
from sepfm_ros.geometry.fundamental.nonlinear import polish_final
from sepfm_ros.geometry.fundamental.refine import iterative_refit, lmeds_refit
from sepfm_ros.geometry.fundamental.shifted_plane import shifted_plane_copy
from sepfm_ros.geometry.fundamental.significance import MAX_LOG10_NFA, consensus_log10_nfa
from sepfm_ros.geometry.fundamental.task import FundamentalTask
from sepfm_ros.geometry.robust.lmeds import lmeds_final_inliers

__all__ = ["finish"]


def finish(problem: FundamentalTask, est: Estimate, F: np.ndarray) -> None:
    """Final model (refit, refinement, plane check), inliers and status into ``est``."""
    if problem.lmeds:
        _finish_lmeds(problem, est, F)
        return
    d, threshold = problem.data, problem.threshold
    t4 = time.perf_counter()
    # its own stream (spawned: the estimate's stream is not advanced), so switching it off
    # changes no other step's draws
    # (the status's stream is spawned here too: spawn(2) gives the children two spawn(1) would)
    inner_rng, status_rng = problem.rng.spawn(2)
    F, scored = inner_sampling(F, problem.whole(), inner_rng, problem.local.inner_samples)
    est.stage2_hypotheses += scored
    F, refits = _final_model(F, d, threshold, problem.local.refine)
    est.stage2_hypotheses += refits  # final refits are scored against all matches too
    plane = None
    check = _plane_check(problem, est, F)
    if check is not None:
        F, plane = check.F, check.reason
    if problem.local.final_polish and problem.local.lo == "lm" and plane is None:
        off_plane = None
        if check is not None and check.H is not None:
            transfer = check.transfer
            if transfer is None:
                transfer = transfer_error(check.H, d.pts1, d.pts2)
            off_plane = transfer >= PLANE_TOLERANCE * threshold
        F = normalize_fundamental(polish_final(F, d, threshold, off_plane))
    est.hypotheses = est.stage1_hypotheses + est.stage2_hypotheses
    est.F = F
    est.inliers = d.distances(F) < threshold
    est.timings_ms["refine"] = 1e3 * (time.perf_counter() - t4)
    _final_status(problem, est, plane, rng=status_rng)


def _plane_check(problem: FundamentalTask, est: Estimate, F: np.ndarray) -> PlaneCheck | None:
    """The dominant-plane check of ``F`` (``degeneracy.plane_and_parallax``) when the options ask
    for it, its candidates counted in ``est``; None when it is off."""
    if not problem.checks.plane_check:
        return None
    d = problem.data
    check = plane_and_parallax(
        F, d.pts1, d.pts2, problem.threshold, problem.rng,
        adaptive=problem.checks.plane_check_adaptive, data=d,
    )  # fmt: skip
    est.stage2_hypotheses += check.candidates
    if (
        problem.checks.shifted_plane_check
        and check.planar
        and not check.replaced
        and check.reason is None
    ):
        check = _periodic_plane_check(problem, est, check)
    return check


def _periodic_plane_check(problem: FundamentalTask, est: Estimate, check: PlaneCheck) -> PlaneCheck:
    """The plane check again without the matches on a period-shifted copy of its plane
    (``shifted_plane.shifted_plane_copy``): they lie off the plane but only say that F's epipole is
    the vanishing point of the texture's period, so they must not count as parallax. Returns
    ``check`` when there is no such copy, else the check on the other matches, where F is
    always challenged by plane-and-parallax candidates (a wrong F through the plane and its
    copy can gather some chance support off them)."""
    d, threshold, H = problem.data, problem.threshold, check.H
    if H is None:  # no plane was found: nothing to discount
        return check
    tol = PLANE_TOLERANCE * threshold  # the plane check's homography tolerance
    inl = d.distances(check.F) < threshold
    transfer = check.transfer if check.transfer is not None else transfer_error(H, d.pts1, d.pts2)
    far = transfer > 2.0 * tol  # its "clear parallax"
    shifted = shifted_plane_copy(H, d.pts1, d.pts2, inl & far, tol, problem.rng, transfer=transfer)
    if shifted is None and not check.accepted:
        # a copy F does not explain: F may still ignore the parallax (unless its support off
        # the plane is far above chance, when the plane check kept it without a challenge)
        shifted = shifted_plane_copy(
            H, d.pts1, d.pts2, far, tol, problem.rng, min_share=0.15, max_iterations=100,
            transfer=transfer,
        )  # fmt: skip
    if shifted is None:
        return check
    keep = ~shifted
    p1, p2 = d.pts1[keep], d.pts2[keep]
    adaptive = problem.checks.plane_check_adaptive
    # F is challenged by plane-and-parallax candidates whatever its support off the plane
    # (min_excess beyond any count), then the kept or replaced F is checked as usual
    challenge = plane_and_parallax(
        check.F, p1, p2, threshold, problem.rng, adaptive=adaptive, min_excess=len(d) + 1
    )
    again = plane_and_parallax(challenge.F, p1, p2, threshold, problem.rng, adaptive=adaptive)
    est.stage2_hypotheses += challenge.candidates + again.candidates
    again.replaced = again.replaced or challenge.replaced
    again.transfer = None  # it was measured on the matches off the copy only
    return again


def _final_status(
    problem: FundamentalTask,
    est: Estimate,
    plane: str | None,
    unreliable: str | None = None,
    rng: np.random.Generator | None = None,
) -> None:
    """``est.status`` from its final inliers: too few, inliers in a band around one line (the
    more specific reason when a plane holds them too: a band lies on many planes), the plane
    check's reason, ``unreliable`` (a method's own reason), or a consensus that random matches
    give as well (``est.log10_nfa`` >= ``MAX_LOG10_NFA``, :mod:`significance`); else left as it
    is. The significance test draws its random re-pairings from a stream of its own, ``rng``
    (spawned from the estimate's when not given)."""
    d, threshold = problem.data, problem.threshold
    k = est.num_inliers
    if k < 8:
        est.set_status(StatusCode.DEGENERATE, f"degenerate: only {k} inliers")
        return
    if rng is None:
        rng = problem.rng.spawn(1)[0]
    assert est.F is not None  # set by the callers before the status
    est.log10_nfa = consensus_log10_nfa(est.F, d, est.inliers, threshold, rng)
    chance = None
    if not est.log10_nfa < MAX_LOG10_NFA:
        chance = (
            f"not significant: {k} of {len(d)} matches within {threshold:g} px, as random "
            f"matches would give (log10 NFA {est.log10_nfa:+.1f})"
        )
    band = line_band_status(d.pts1[est.inliers], d.pts2[est.inliers], threshold)
    for code, text in (
        (StatusCode.DEGENERATE, band or plane),
        (StatusCode.UNRELIABLE, unreliable),
        (StatusCode.NOT_SIGNIFICANT, chance),
    ):
        if text:
            est.set_status(code, text)
            return


def _final_model(
    F: np.ndarray, data: Correspondences, threshold: float, refine: bool
) -> tuple[np.ndarray, int]:
    """Refit on all inliers (normalised eight-point), optionally Sampson-refined, rank 2.

    Returns (F, number of refitted models scored). A refit replaces F only if it lowers the
    MSAC cost at ``threshold`` (see :func:`iterative_refit`).
    """
    fitted = iterative_refit(F, data, threshold, irls_iterations=2 if refine else 0)
    candidates = np.ascontiguousarray(np.stack([F, *fitted]))
    cost, _ = msac_kernel(candidates, data.X1, data.X2, threshold)
    return normalize_fundamental(candidates[int(np.argmin(cost))]), len(fitted)


def _median_sq(F: np.ndarray, data: Correspondences) -> np.ndarray:
    """Median squared symmetric epipolar distance (px^2) of (3, 3) or (K, 3, 3) models."""
    d = data.distances(np.ascontiguousarray(F))
    return np.median(d * d, axis=-1)


def _final_model_lmeds(
    F: np.ndarray, data: Correspondences, model_points: int, refine: bool
) -> tuple[np.ndarray, int]:
    """LMedS final model: F and its refits on its robust inliers (:func:`lmeds_refit`, Sampson
    IRLS with ``refine``), the lowest median kept. Returns (F, number of refits scored)."""
    fitted = lmeds_refit(F, data, model_points, irls_iterations=2 if refine else 0)
    candidates = np.ascontiguousarray(np.stack([F, *fitted]))
    return normalize_fundamental(candidates[int(np.argmin(_median_sq(candidates, data)))]), len(
        fitted
    )


def _finish_lmeds(problem: FundamentalTask, est: Estimate, F: np.ndarray) -> None:
    """:func:`finish` of the LMedS methods: the final model by median, the plane check as a
    degeneracy test (``threshold``), inliers from the robust scale, the breakdown check."""
    d, threshold = problem.data, problem.threshold
    t4 = time.perf_counter()
    F, refits = _final_model_lmeds(F, d, problem.model_points, problem.local.refine)
    est.stage2_hypotheses += refits
    plane = None
    check = _plane_check(problem, est, F)
    if check is not None:
        plane = check.reason
        if check.replaced:
            # the check found F without support off a dominant plane; its plane-and-parallax
            # model is taken only if it does not raise the median
            if _median_sq(check.F, d) <= _median_sq(F, d):
                F = check.F
            elif plane is None:
                plane = "degenerate: dominant plane (the least-median F has no support off it)"
    est.hypotheses = est.stage1_hypotheses + est.stage2_hypotheses
    est.F = F
    est.inliers, est.scale, _ = lmeds_final_inliers(d.distances(F), problem.model_points)
    est.timings_ms["refine"] = 1e3 * (time.perf_counter() - t4)
    unreliable = None
    if est.scale > threshold:
        unreliable = (
            f"unreliable: robust scale {est.scale:.2f} px exceeds the threshold {threshold:g} px "
            "(more than half of the matches are outliers, beyond LMedS's breakdown point, or "
            "the noise exceeds the threshold)"
        )
    _final_status(problem, est, plane, unreliable)
