"""The stopping rule of the robust loop: the paper's F(k, r) at the best model's inlier ratio,
capped at ``max_samples``, at least ``min_samples``; with the SPRT, the all-inlier probability is
scaled by the chance 1 - 1/A that the SPRT accepts a good model (Matas & Chum 2008, eq. 3)."""

from __future__ import annotations

import math

import numba
import numpy as np

from sepfm_ros.geometry.robust.trials import trial_count, trials_needed

__all__ = ["StoppingRule", "samples_needed"]


class StoppingRule:
    """Samples needed before the loop may stop.

    Args:
        confidence: p, the probability of having drawn one all-inlier sample.
        max_samples: cap on the result.
        min_samples: floor of the result.
    """

    def __init__(self, confidence: float, max_samples: int, min_samples: int) -> None:
        self.confidence, self.max_samples, self.min_samples = confidence, max_samples, min_samples
        self._memo: dict[tuple[int, int, int, float], int] = {}

    def needed(self, k: int, n: int, count: int, sprt_A: float = np.inf) -> int:
        """Samples of ``k`` points needed when the best model has ``count`` of ``n`` points as
        inliers (``count`` < 0: none yet; the cap), with the SPRT at threshold ``sprt_A``
        (inf: no SPRT). Memoised: it changes only with the count and A."""
        key = (k, n, count, sprt_A)
        need = self._memo.get(key)
        if need is None:
            need = self._memo[key] = self._needed(k, n, count, sprt_A)
        return need

    def _needed(self, k: int, n: int, count: int, sprt_A: float) -> int:
        return int(
            samples_needed(
                k, n, count, float(sprt_A), self.confidence, self.max_samples, self.min_samples
            )
        )


@numba.njit(cache=True, nogil=True)
def samples_needed(
    k: int, n: int, count: int, A: float, confidence: float, max_samples: int, min_samples: int
) -> int:
    """:meth:`StoppingRule.needed` (compiled, shared with the compiled loop of
    :mod:`~sepfm_ros.geometry.fundamental.loop_kernel`): samples of ``k`` points needed when
    the best model has ``count`` of ``n`` points as inliers, with the SPRT at threshold ``A``
    (inf: no SPRT), capped at ``max_samples``, at least ``min_samples``."""
    count = max(count, 0)
    if math.isfinite(A) and n > 0:
        # SPRT rejects a good model with probability <= 1 / A: an all-inlier sample
        # yields an accepted model with probability w^k (1 - 1/A) (Matas & Chum, eq. 3)
        w = min(1.0, count / n) ** float(k) * (1.0 - 1.0 / A)
        need = int(min(trial_count(1, w, confidence), float(max_samples)))
    else:
        need = trials_needed(k, count, n, confidence, max_samples)
    return max(need, min_samples)
