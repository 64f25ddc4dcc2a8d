"""The figures of a detector's outcomes on a labelled corpus: ROC-AUC, precision, recall, F1,
false alarms per 100 unchanged builds and the recall of large changes (`redline.detect.evaluate`
makes the outcomes)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

#: "Changes of 10 % or more" (the issue's recall goal), by the size `change_sizes` measures.
LARGE_CHANGE = 0.10


@dataclass(frozen=True)
class Outcome:
    positive: bool
    score: float
    flagged: bool
    decided: bool
    size: float = math.nan  # a positive's change size (`change_sizes`); NaN for a negative
    series: str = ""
    build: int = 0
    verdict: str = ""
    confirmation: str = ""  # with confirmation: suspected, held or dropped (flagged units)


@dataclass(frozen=True)
class MethodScores:
    roc_auc: float
    precision: float
    recall: float
    f1: float
    tp: int
    fp: int
    fn: int
    units: int
    decided: int
    false_alarms_per_100: float = math.nan  # FP per 100 negative units (unchanged builds)
    recall_large: float = math.nan  # recall of the positives whose change is >= LARGE_CHANGE
    large: int = 0  # how many such positives there are

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def roc_auc(positive: Sequence[bool], scores: Sequence[float]) -> float:
    """Area under the ROC curve as P(score of a positive > score of a negative), ties 1/2.

    NaN when the units hold no positive or no negative.
    """
    labels = np.asarray(positive, dtype=bool)
    n_pos, n_neg = int(labels.sum()), int((~labels).sum())
    if n_pos == 0 or n_neg == 0:
        return math.nan
    from scipy.stats import rankdata  # where it runs: see `redline.detect`

    ranks = rankdata(np.asarray(scores, dtype=np.float64))
    return float((ranks[labels].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def precision_recall_f1(
    positive: Sequence[bool], flagged: Sequence[bool]
) -> tuple[float, float, float, int, int, int]:
    """(precision, recall, F1, tp, fp, fn); a ratio with a zero denominator is 0."""
    labels, flags = np.asarray(positive, dtype=bool), np.asarray(flagged, dtype=bool)
    tp = int((labels & flags).sum())
    fp = int((~labels & flags).sum())
    fn = int((labels & ~flags).sum())
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / (tp + fn) if tp + fn else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return precision, recall, f1, tp, fp, fn


def summarize(outcomes: Sequence[Outcome]) -> MethodScores:
    positive = [o.positive for o in outcomes]
    precision, recall, f1, tp, fp, fn = precision_recall_f1(positive, [o.flagged for o in outcomes])
    negatives = len(outcomes) - sum(positive)
    large = [o for o in outcomes if o.positive and o.size >= LARGE_CHANGE]
    return MethodScores(
        roc_auc=roc_auc(positive, [o.score for o in outcomes]),
        precision=precision,
        recall=recall,
        f1=f1,
        tp=tp,
        fp=fp,
        fn=fn,
        units=len(outcomes),
        decided=sum(o.decided for o in outcomes),
        false_alarms_per_100=100 * fp / negatives if negatives else math.nan,
        recall_large=(sum(o.flagged for o in large) / len(large) if large else math.nan),
        large=len(large),
    )
