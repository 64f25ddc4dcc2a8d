"""E-divisive means: change points in one series' revision history, with a permutation test.

Matteson & James, "A Nonparametric Approach for Multiple Change Point Analysis of
Multivariate Data", JASA 2014 (R package ``ecp``, function ``e.divisive``). Bisect the
series where the energy distance between the two sides is largest, test that split with a
permutation test, and repeat on the pieces until a split is not significant.

Defaults: ``sig_level = 0.05``, ``permutations = 199`` and ``alpha = 1`` are ``e.divisive``'s;
``min_size = 5`` is ours (``ecp`` uses 30 samples, longer than many revision histories; the
SAP series have 27 to 471 builds). As in MongoDB's signal-processing implementation, the
right end of a split is the segment's end (``ecp`` also searches it) and permutations shuffle
only the segment being split. The effect-size floor ``min_effect = 0.10`` keeps significant
but tiny changes out of ``reported``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Self

import numpy as np
from redline.detect.result import CHANGE, NO_CHANGE, NOT_ENOUGH_DATA, check_samples


@dataclass(frozen=True)
class ChangePoint:
    index: int  # first position of the new segment
    p_value: float
    statistic: float  # the scaled energy statistic Q at the split
    effect: float = 0.0  # relative change of the mean from the segment before to the one after
    reported: bool = True  # |effect| reaches the floor


@dataclass(frozen=True)
class ChangePoints:
    verdict: str
    change_points: tuple[ChangePoint, ...] = field(default=())
    reason: str = ""


def split_statistics(x: np.ndarray, min_size: int, alpha: float) -> np.ndarray:
    """Q(tau) for every split tau in [min_size, n - min_size] (NaN elsewhere), in O(n^2)."""
    n = len(x)
    distance = np.abs(x[:, None] - x[None, :]) ** alpha
    prefix = np.zeros((n + 1, n + 1))
    prefix[1:, 1:] = distance.cumsum(axis=0).cumsum(axis=1)
    tau = np.arange(min_size, n - min_size + 1)
    left = prefix[tau, tau]
    cross = prefix[tau, n] - left
    right = prefix[n, n] - left - 2 * cross
    energy = (
        2 * cross / (tau * (n - tau))
        - left / (tau * (tau - 1))
        - right / ((n - tau) * (n - tau - 1))
    )
    q = np.full(n + 1, np.nan)
    q[tau] = tau * (n - tau) / n * energy
    return q


def _relative_change(before: np.ndarray, after: np.ndarray) -> float:
    mean = float(np.mean(before))
    return 0.0 if mean == 0 else (float(np.mean(after)) - mean) / abs(mean)


class EDivisive:
    """Multiple change points in one series (values in revision order)."""

    def __init__(
        self,
        sig_level: float = 0.05,
        permutations: int = 199,
        min_size: int = 5,
        alpha: float = 1.0,
        min_effect: float = 0.10,
        random_state: int = 0,
    ) -> None:
        self.sig_level = sig_level
        self.permutations = permutations
        self.min_size = min_size
        self.alpha = alpha
        self.min_effect = min_effect
        self.random_state = random_state

    def fit(self, series: object) -> Self:
        self.result_ = self.detect(series)
        return self

    def detect(self, series: object) -> ChangePoints:
        checked = check_samples(
            series, np.empty(0), min_baseline=2 * self.min_size, min_candidate=0
        )
        if isinstance(checked, str):
            reason = checked.replace("baseline", "series")
            return ChangePoints(verdict=NOT_ENOUGH_DATA, reason=reason)
        x = checked[0]
        rng = np.random.default_rng(self.random_state)
        found = self._bisect(x, rng)
        bounds = [0, *sorted(index for index, _, _ in found), len(x)]
        points = []
        for index, p_value, statistic in found:
            at = bounds.index(index)
            effect = _relative_change(x[bounds[at - 1] : index], x[index : bounds[at + 1]])
            points.append(
                ChangePoint(index, p_value, statistic, effect, abs(effect) >= self.min_effect)
            )
        verdict = CHANGE if any(p.reported for p in points) else NO_CHANGE
        return ChangePoints(verdict=verdict, change_points=tuple(points))

    def _bisect(self, x: np.ndarray, rng: np.random.Generator) -> list[tuple[int, float, float]]:
        """Significant splits as (index, p-value, Q), in the order they were found."""
        found: list[tuple[int, float, float]] = []
        while True:
            cuts = sorted(index for index, _, _ in found)
            best = self._best_split(x, [0, *cuts, len(x)])
            if best is None:
                return found
            start, end, tau, q = best
            p_value = self._permutation_p(x[start:end], q, rng)
            if p_value > self.sig_level:
                return found
            found.append((start + tau, p_value, q))

    def _best_split(self, x: np.ndarray, bounds: list[int]) -> tuple[int, int, int, float] | None:
        best = None
        for start, end in zip(bounds, bounds[1:], strict=False):
            if end - start < 2 * self.min_size:
                continue
            q = split_statistics(x[start:end], self.min_size, self.alpha)
            tau = int(np.nanargmax(q))
            if best is None or q[tau] > best[3]:
                best = (start, end, tau, float(q[tau]))
        return best

    def _permutation_p(
        self, segment: np.ndarray, observed: float, rng: np.random.Generator
    ) -> float:
        exceed = sum(
            np.nanmax(split_statistics(rng.permutation(segment), self.min_size, self.alpha))
            >= observed
            for _ in range(self.permutations)
        )
        return float((exceed + 1) / (self.permutations + 1))
