"""Shang et al. (2015): regression models on clustered counters; the score is a prediction error.

Shang, Hassan, Nasser, Flora: "Automated Detection of Performance Regressions Using Regression
Models on Clustered Performance Counters", ICPE 2015, as Wienke & Wrede (2016, section 4.4.3)
use it: cluster the counters by correlation on the baseline, in each cluster regress one
counter on the others (trained on the baseline), and measure how much worse the models
predict the candidate than the baseline; one score per cluster.

Simplifications (documented, not the paper's): clusters come from average-linkage
hierarchical clustering on 1 - |Pearson r| cut at ``1 - min_correlation`` (Shang et al. choose
the cut with the Calinski-Harabasz index); the dependent counter is the one most correlated
with the rest of its cluster; the baseline error is the leave-one-out error (not the
optimistic in-sample one). A cluster of one counter gets an intercept-only model, so for a
single series the score is the candidate's mean distance from the baseline mean, relative to
the baseline's own.
"""

from __future__ import annotations

import numpy as np
from redline.detect.aggregate import aggregate_scores
from redline.detect.methods import Detector
from redline.detect.result import (
    CHANGE,
    NO_CHANGE,
    Detection,
    direction_of,
    largest,
    passes_floor,
    relative_effects,
)


def cluster_counters(base: np.ndarray, min_correlation: float) -> list[np.ndarray]:
    """Groups of counter indices; counters constant in the baseline stay alone."""
    spread = np.ptp(base, axis=0) > 0
    varying = np.nonzero(spread)[0]
    alone = [np.array([j]) for j in np.nonzero(~spread)[0]]
    if len(varying) < 2:
        return alone + [np.array([j]) for j in varying]
    with np.errstate(invalid="ignore", divide="ignore"):
        distance = 1.0 - np.abs(np.corrcoef(base[:, varying], rowvar=False))
    distance = np.nan_to_num((distance + distance.T) / 2, nan=1.0)
    np.fill_diagonal(distance, 0.0)
    from scipy.cluster.hierarchy import fcluster, linkage  # where it runs: see `redline.detect`
    from scipy.spatial.distance import squareform

    labels = fcluster(
        linkage(squareform(distance, checks=False), method="average"),
        t=1.0 - min_correlation,
        criterion="distance",
    )
    return alone + [varying[labels == label] for label in np.unique(labels)]


def _design(base: np.ndarray, others: np.ndarray) -> np.ndarray:
    return np.column_stack([np.ones(len(base)), base[:, others]])


def cluster_errors(base: np.ndarray, cand: np.ndarray, members: np.ndarray) -> tuple[float, float]:
    """(baseline leave-one-out error, candidate error) of one cluster's model, both relative."""
    if len(members) == 1:
        target, others = members[0], members[:0]
    else:
        corr = np.abs(np.corrcoef(base[:, members], rowvar=False))
        target = members[int(np.argmax(np.nansum(corr, axis=0)))]
        others = members[members != target]
    x_base, y_base = _design(base, others), base[:, target]
    coef, *_ = np.linalg.lstsq(x_base, y_base, rcond=None)
    leverage = np.einsum("ij,ji->i", x_base, np.linalg.pinv(x_base))
    loo = (y_base - x_base @ coef) / np.maximum(1.0 - leverage, 0.01)
    scale = max(float(np.mean(np.abs(y_base))), 1e-12)
    error_cand = np.abs(cand[:, target] - _design(cand, others) @ coef)
    return float(np.mean(np.abs(loo))) / scale, float(np.mean(error_cand)) / scale


class ShangRegression(Detector):
    """Shang et al. 2015 on samples x counters; the score aggregates per-cluster error growth.

    A cluster's score is max(0, candidate error - baseline error), both relative to the mean
    of the dependent counter. Defaults (ours): ``min_correlation = 0.7`` for a cluster,
    a change when a cluster's error grows by ``min_error_change = 0.10`` (10 % of the counter's
    mean) on a counter whose mean moved by ``min_effect = 0.10`` (the per-counter floor; a
    float or one per counter), ``aggregate = "max"`` (the paper's best for Shang et al.).
    """

    name = "shang"
    ndim = 2

    def __init__(
        self,
        min_correlation: float = 0.7,
        min_error_change: float = 0.10,
        min_effect: float | np.ndarray = 0.10,
        aggregate: str = "max",
        min_baseline: int = 5,
        min_candidate: int = 1,
    ) -> None:
        self.min_correlation = min_correlation
        self.min_error_change = min_error_change
        self.min_effect = min_effect
        self.aggregate = aggregate
        self.min_baseline = min_baseline
        self.min_candidate = min_candidate

    def _detect(self, base: np.ndarray, cand: np.ndarray) -> Detection:
        clusters = cluster_counters(base, self.min_correlation)
        growth = np.array(
            [
                max(0.0, after - before)
                for before, after in (cluster_errors(base, cand, members) for members in clusters)
            ]
        )
        effects = relative_effects(base, cand)
        floor = passes_floor(effects, self.min_effect)
        reported = [
            members[floor[members]]
            for members, grew in zip(clusters, growth, strict=True)
            if grew >= self.min_error_change
        ]
        counters = np.concatenate(reported) if reported else np.array([], dtype=int)
        effect = largest(effects[counters]) if len(counters) else largest(effects)
        return Detection(
            method=self.name,
            verdict=CHANGE if len(counters) else NO_CHANGE,
            score=aggregate_scores(growth, self.aggregate),
            effect=effect,
            direction=direction_of(effect),
            parts=tuple(growth.tolist()),
            reason=f"prediction error grew on counters {sorted(counters.tolist())}"
            if len(counters)
            else "",
        )
