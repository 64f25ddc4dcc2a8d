"""Summary statistics of samples: what a summary row holds, what one revision's executions pool
to, what a comparison shows. Pure numpy, like every other statistic of Redline's."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

QUANTILES = {"p5": 5, "p25": 25, "p50": 50, "p75": 75, "p95": 95}
#: the quantile sketch: 32 evenly spaced levels, mid-bucket (1/64, 3/64, ... 63/64); enough to
#: redraw the distribution and to compare it once the raw samples are pruned
SKETCH_LEVELS = (np.arange(32) + 0.5) / 32


def summarize(values: np.ndarray) -> dict[str, Any] | None:
    """n, mean, std (population), min, max, the quantiles and the sketch of one series.

    Only finite samples count (``n`` is how many there were); None when there is none. The raw
    samples, NaN and infinities included, stay in the Parquet table for detection to judge.
    """
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    stats: dict[str, Any] = {
        "n": int(values.size),
        "mean": float(values.mean()),
        "std": float(values.std()),
        "min": float(values.min()),
        "max": float(values.max()),
    }
    for name, value in zip(QUANTILES, np.percentile(values, list(QUANTILES.values())), strict=True):
        stats[name] = float(value)
    stats["sketch"] = [float(v) for v in np.quantile(values, SKETCH_LEVELS)]
    return stats


def describe(values: np.ndarray) -> dict[str, float | int]:
    """n, mean, std (population), min, max and median of a non-empty array."""
    return {
        "n": int(values.size),
        "mean": float(values.mean()),
        "std": float(values.std()),
        "min": float(values.min()),
        "max": float(values.max()),
        "p50": float(np.median(values)),
    }


@dataclass
class Pooled:
    """Summaries (n, mean, population std) of parts pooled into those of the whole: one
    revision's point from its executions' summaries."""

    n: int = 0
    total: float = 0.0
    squares: float = 0.0

    def add(self, n: int, mean: float, std: float) -> None:
        self.n += n
        self.total += n * mean
        self.squares += n * (std * std + mean * mean)

    @property
    def mean(self) -> float:
        return self.total / self.n

    @property
    def std(self) -> float:
        return math.sqrt(max(self.squares / self.n - self.mean * self.mean, 0.0))
