"""Scoring a history's change points as the field does: TCPDBench's F1 with a margin.

van den Burg & Williams (2020, "An evaluation of change point detection algorithms", the
TCPDBench benchmark): a predicted change point is a true positive when it lies within
``margin`` builds of an annotated one, each annotated point matched at most once; precision is
over the union of the annotators' points, recall the mean of each annotator's, and
F = P R / (alpha R + (1 - alpha) P) with alpha 0.5 (the harmonic mean). As there, the start of
the series counts as a change point in every set, so a detector that never alarms is scored
(precision 1, recall 1 / (annotated + 1)) and an empty annotation is not a division by zero.

Besides Redline's own walk (its flagged builds, confirmed by history when asked), two
references: a detector that never alarms (`zero`) and binary segmentation over each series'
build medians (`ruptures.Binseg`, least squares, penalty 2 sigma^2 log n with sigma from the
median absolute difference of neighbouring builds: BIC's choice for a mean shift).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

MARGIN = 5


def _true_positives(truth: set[int], predicted: set[int], margin: int) -> int:
    """Annotated points matched by a prediction within ``margin``, each at most once (the
    nearest unused prediction first, as TCPDBench's greedy matching)."""
    used: set[int] = set()
    found = 0
    for point in sorted(truth):
        close = sorted((abs(p - point), p) for p in predicted - used if abs(p - point) <= margin)
        if close:
            used.add(close[0][1])
            found += 1
    return found


def f_measure(
    annotations: Mapping[str, Sequence[int]],
    predicted: Sequence[int],
    margin: int = MARGIN,
    alpha: float = 0.5,
) -> tuple[float, float, float]:
    """(F, precision, recall) of ``predicted`` against each annotator's points (indices into
    the series; 0, the start, is added to every set)."""
    prediction = {0, *predicted}
    truths = [{0, *points} for points in annotations.values()] or [{0}]
    union = set().union(*truths)
    precision = _true_positives(union, prediction, margin) / len(prediction)
    recall = float(np.mean([_true_positives(t, prediction, margin) / len(t) for t in truths]))
    if precision == 0 and recall == 0:
        return 0.0, 0.0, 0.0
    f = precision * recall / (alpha * recall + (1 - alpha) * precision)
    return f, precision, recall


def binary_segmentation(levels: Sequence[float] | np.ndarray) -> list[int]:
    """Change points of a series of build levels by binary segmentation (`ruptures`), as the
    indices of the first build after each change."""
    import ruptures

    signal = np.asarray(levels, dtype=float)
    if len(signal) < 4:
        return []
    spread = float(np.median(np.abs(np.diff(signal)))) / (0.6745 * math.sqrt(2))
    sigma = spread if spread > 0 else float(np.std(signal)) or 1.0
    penalty = 2 * sigma**2 * math.log(len(signal))
    ends = ruptures.Binseg(model="l2", min_size=2, jump=1).fit(signal).predict(pen=penalty)
    return [end for end in ends if end < len(signal)]
