"""Foo et al. (2010): association rules on discretized counters; the score is a confidence change.

Foo, Jiang, Adams, Hassan, Zou, Flora: "Mining Performance Regression Testing Repositories for
Automated Performance Analysis", QSIC 2010, as Wienke & Wrede (2016, section 4.4.3) use it:
discretize each counter, mine association rules between counter levels on the baseline, and
measure how much each rule's confidence changes in the candidate; one score per rule.

Simplifications (documented defaults, not the paper's): levels are "low" / "normal" / "high"
at the baseline mean -/+ ``z`` standard deviations (Foo et al. discretize too, with their own
bins); rules have one premise item or none (``{} -> item``, whose confidence is the item's
frequency, which keeps the method meaningful for a single counter), not Apriori's itemsets.
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
    not_enough,
    passes_floor,
    relative_effects,
)

LEVELS = 3  # low, normal, high


def discretize(values: np.ndarray, mean: np.ndarray, std: np.ndarray, z: float) -> np.ndarray:
    """One-hot items, shape samples x (counters * 3): column 3*j + level for counter j."""
    low = values < mean - z * std
    high = values > mean + z * std
    level = np.where(low, 0, np.where(high, 2, 1))
    items = np.zeros((values.shape[0], values.shape[1] * LEVELS), dtype=np.float64)
    rows = np.arange(values.shape[0])[:, None]
    items[rows, np.arange(values.shape[1]) * LEVELS + level] = 1.0
    return items


def mine_rules(
    items: np.ndarray, min_support: float, min_confidence: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rules premise -> consequence as (premise item or -1, consequence item, confidence)."""
    n = items.shape[0]
    support = items.mean(axis=0)
    together = items.T @ items / n
    with np.errstate(divide="ignore", invalid="ignore"):
        confidence = together / support[:, None]
    counter = np.arange(items.shape[1]) // LEVELS
    ok = (
        (together >= min_support)
        & (confidence >= min_confidence)
        & (counter[:, None] != counter[None, :])
    )
    premise, consequence = np.nonzero(ok)
    empty = np.nonzero(support >= min_confidence)[0]
    return (
        np.concatenate([premise, np.full(len(empty), -1)]),
        np.concatenate([consequence, empty]),
        np.concatenate([confidence[premise, consequence], support[empty]]),
    )


def rule_confidence(items: np.ndarray, premise: np.ndarray, consequence: np.ndarray) -> np.ndarray:
    """Each rule's confidence in ``items``; NaN where the premise never occurs."""
    n = items.shape[0]
    support = items.mean(axis=0)
    together = items.T @ items / n
    with np.errstate(divide="ignore", invalid="ignore"):
        conditional = together[premise, consequence] / support[premise]
    return np.where(premise < 0, support[consequence], conditional)


class FooRules(Detector):
    """Foo et al. 2010 on samples x counters; the score aggregates per-rule |confidence change|.

    Defaults (ours; Foo et al. tune theirs per system): ``z = 2`` (about 95 % of a normal
    baseline is "normal"), ``min_support = 0.1`` and ``min_confidence = 0.9`` for the mined
    rules, a rule is violated when its confidence moves by ``min_confidence_change = 0.3``, and
    a change is reported only for counters whose mean moved by ``min_effect = 0.10`` (the
    per-counter effect-size floor; a float or one per counter). ``aggregate = "max"``.
    """

    name = "foo"
    ndim = 2

    def __init__(
        self,
        z: float = 2.0,
        min_support: float = 0.1,
        min_confidence: float = 0.9,
        min_confidence_change: float = 0.3,
        min_effect: float | np.ndarray = 0.10,
        aggregate: str = "max",
        min_baseline: int = 5,
        min_candidate: int = 1,
    ) -> None:
        self.z = z
        self.min_support = min_support
        self.min_confidence = min_confidence
        self.min_confidence_change = min_confidence_change
        self.min_effect = min_effect
        self.aggregate = aggregate
        self.min_baseline = min_baseline
        self.min_candidate = min_candidate

    def _detect(self, base: np.ndarray, cand: np.ndarray) -> Detection:
        mean, std = base.mean(axis=0), base.std(axis=0, ddof=1)
        base_items = discretize(base, mean, std, self.z)
        premise, consequence, before = mine_rules(base_items, self.min_support, self.min_confidence)
        if len(consequence) == 0:
            return not_enough(
                self.name,
                "no association rule in the baseline reaches support "
                f"{self.min_support} and confidence {self.min_confidence}",
            )
        after = rule_confidence(discretize(cand, mean, std, self.z), premise, consequence)
        known = ~np.isnan(after)
        if not known.any():
            return not_enough(self.name, "no rule's premise occurs in the candidate")
        changes = np.abs(before[known] - after[known])
        effects = relative_effects(base, cand)
        violated = np.unique(consequence[known][changes >= self.min_confidence_change] // LEVELS)
        floor = passes_floor(effects, self.min_effect)
        reported = violated[floor[violated]] if len(violated) else violated
        effect = largest(effects[reported]) if len(reported) else largest(effects)
        return Detection(
            method=self.name,
            verdict=CHANGE if len(reported) else NO_CHANGE,
            score=aggregate_scores(changes, self.aggregate),
            effect=effect,
            direction=direction_of(effect),
            parts=tuple(changes.tolist()),
            reason=f"violated rules on counters {reported.tolist()}" if len(reported) else "",
        )
