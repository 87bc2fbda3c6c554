"""The paper's escape (Sec. 1: "in cases where such a configuration does not exist, standard
RANSAC can be applied with overall small overhead"): per pair, whether the line search can pay
for itself.

The separable method needs F(3, r) samples of stage 1 (H_e, one model each) and F(k - 3, r)
samples of stage 2 (k = 7 or 8) after the line search, where standard RANSAC needs F(k, r)
(the paper's Observation 2). The line search itself costs about as much as
:data:`LINE_SEARCH_HYPOTHESES` F hypotheses. The inlier ratio comes from a probe: the first
:data:`PROBE_SAMPLES` PROSAC samples of the standard loop over all matches, which, ranked best
first, show the inlier ratio of a clean pair at once. The probe scores minimal-sample models only,
so on a hard pair, where the line search is kept, it costs a few hypotheses; only when
:data:`PROBE_LO_GAIN` times its inlier count could reach the break-even ratio is its best model
optimised locally (one local optimisation) and counted again. When the separable path cannot
beat the standard one at that ratio, the standard loop simply goes on from the probe (nothing of
it is wasted: the probe is that loop's start).
"""

from __future__ import annotations

import copy
import math
from typing import NamedTuple

import numpy as np

from sepfm_ros.geometry.robust.trials import trial_count
from sepfm_ros.geometry.separable.options import LINE_SEARCH_HYPOTHESES

__all__ = [
    "LINE_SEARCH_HYPOTHESES",
    "MODELS_PER_SAMPLE",
    "PROBE_LO_GAIN",
    "PROBE_SAMPLES",
    "copy_generator",
    "EscapeCosts",
    "escape_costs",
    "line_search_pays",
]

#: Samples of the probe: the first PROSAC samples of the standard loop (with PROSAC's default
#: schedule they come from the top ``PROBE_SAMPLES + 6`` matches of a seven-point loop).
PROBE_SAMPLES = 8
#: How much one local optimisation raises the probe's best minimal-sample inlier count, at most
#: (a bound for the decision, not an estimate): its ratio of counts is 1.2-1.5 at the median
#: and 1.8-2.2 at the 90th percentile on the shared and line-rich pairs (SIFT 0.75 and 0.95).
#: A probe below the break-even ratio by more than this keeps the line search without it; a
#: larger gain on a rare pair costs only the time the escape would have saved.
PROBE_LO_GAIN = 3.0
#: Models per seven-point (or stage-2) sample: the real roots of the cubic, about 1.5 on the
#: shared pairs (ransac7's models per sample, local optimisation left out); stage 1's 3-point
#: samples give one H_e each.
MODELS_PER_SAMPLE = 1.5


class EscapeCosts(NamedTuple):
    """Expected F hypotheses of the two ways to finish a pair (:func:`escape_costs`)."""

    separable: float  #: F(3, r) + m F(k - 3, r) + the line search's cost
    standard: float  #: m F(k, r)


def escape_costs(
    inlier_ratio: float,
    model_points: int,
    confidence: float,
    line_search_hypotheses: float = LINE_SEARCH_HYPOTHESES,
    models_per_sample: float = MODELS_PER_SAMPLE,
) -> EscapeCosts:
    """Expected cost, in F hypotheses, of the two ways to finish a pair.

    Args:
        inlier_ratio: w = 1 - r, the inlier ratio the probe shows, in [0, 1].
        model_points: k, 7 (seven-point solver) or 8.
        confidence: p of F(k, r).
        line_search_hypotheses: the line search's cost in F hypotheses (>= 0).
        models_per_sample: F models per k-point sample (>= 1); stage 1's are H_e, one each.
    Returns:
        (separable, standard): F(3, r) + m F(k - 3, r) + the line search's cost, and m F(k, r),
        with m = ``models_per_sample``; inf where no sample can be all inliers.
    """
    if not 0.0 <= inlier_ratio <= 1.0 or math.isnan(inlier_ratio):
        raise ValueError(f"inlier_ratio must be in [0, 1], got {inlier_ratio}")
    if model_points not in (7, 8):
        raise ValueError(f"model_points must be 7 or 8, got {model_points}")
    m = float(models_per_sample)
    separable = (
        trial_count(3, inlier_ratio, confidence)
        + m * trial_count(model_points - 3, inlier_ratio, confidence)
        + float(line_search_hypotheses)
    )
    standard = m * trial_count(model_points, inlier_ratio, confidence)
    return EscapeCosts(float(separable), float(standard))


def line_search_pays(
    inlier_ratio: float,
    model_points: int,
    confidence: float,
    line_search_hypotheses: float = LINE_SEARCH_HYPOTHESES,
    models_per_sample: float = MODELS_PER_SAMPLE,
) -> bool:
    """True when the separable path is expected to score fewer hypotheses than standard
    RANSAC at ``inlier_ratio`` (ties go to standard RANSAC: nothing to gain, a line search to
    pay), and when F(k, r) is infinite (no model seen: the limit w -> 0, where F(k, r) grows
    fastest). Arguments: those of :func:`escape_costs`."""
    costs = escape_costs(
        inlier_ratio, model_points, confidence, line_search_hypotheses, models_per_sample
    )
    # F(k, r) infinite (no model, or w^k below the float range): as w -> 0 it outgrows the rest
    return costs.separable < costs.standard or math.isinf(costs.standard)


def copy_generator(rng: np.random.Generator) -> np.random.Generator:
    """An independent generator in ``rng``'s state: it draws what ``rng`` would draw next, and
    its ``spawn`` gives the children ``rng``'s would (a copy of the seed sequence, so spawning
    from one does not advance the other); ``rng`` is left as it was."""
    seq = rng.bit_generator.seed_seq
    if not isinstance(seq, np.random.SeedSequence):  # e.g. a generator made from a state
        return copy.deepcopy(rng)
    seq = np.random.SeedSequence(
        seq.entropy, spawn_key=seq.spawn_key, pool_size=seq.pool_size,
        n_children_spawned=seq.n_children_spawned,
    )  # fmt: skip
    bit = type(rng.bit_generator)(seq)
    bit.state = rng.bit_generator.state
    return np.random.Generator(bit)
