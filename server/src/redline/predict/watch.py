"""Run-time fault detection with a resource model: the live counterpart of the features' input,
and the residual between measured and predicted usage, smoothed, against a threshold calibrated
on validation data (Wienke & Wrede, Section 6; `redline watch` wires it to zenoh and /proc).

`EventWindow` keeps what a live subscriber heard in the longest window, and extracts features with
the very function training used (`redline.predict.features.extract`). `Residuals` smooths the
residual (an exponentially weighted mean) and raises an alarm once it stays beyond the threshold
for `HOLD` steps in a row; the alarm ends when it has been back within for as long.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import numpy as np
from redline.predict.features import NS, Event, FeatureSpec, extract

#: weight of the newest residual in the smoothed one (one step a second)
SMOOTHING = 0.3
#: steps in a row beyond (or back within) the threshold that start (or end) an alarm
HOLD = 3
#: the threshold: this many times the largest smoothed residual of the validation data
#: (its 99.9th percentile), so that the model's own errors do not alarm
MARGIN = 2.0
#: and at least this share of the target's typical level (a model that fits its training data
#: all but exactly, e.g. a constant RSS, would otherwise alarm at any wobble)
FLOOR = 0.05


def smooth(residuals: np.ndarray, weight: float = SMOOTHING) -> np.ndarray:
    out = np.empty(len(residuals))
    level = 0.0
    for index, value in enumerate(residuals):
        level = weight * value + (1 - weight) * level if index else value
        out[index] = level
    return out


def calibrate(residuals_by_group: list[np.ndarray], level: float, margin: float = MARGIN) -> float:
    """The alarm threshold from out-of-fold residuals (one array per group, in time order) and
    the target's typical ``level`` (its mean absolute value)."""
    smoothed = np.concatenate([np.abs(smooth(r)) for r in residuals_by_group if len(r)])
    if not len(smoothed):
        return float("inf")
    return float(max(margin * np.quantile(smoothed, 0.999), FLOOR * abs(level)))


class EventWindow:
    """The samples a live subscriber heard, kept for the longest window (thread-safe: zenoh's
    callbacks add from their own threads)."""

    def __init__(self, spec: FeatureSpec) -> None:
        self.spec = spec
        self._keep_ns = int(max(spec.windows) * NS)
        self._events: deque[Event] = deque()
        self._lock = threading.Lock()

    def add(self, key: str, stamp_ns: int, size: int) -> None:
        with self._lock:
            self._events.append((key, stamp_ns, size))

    def heard(self, now_ns: int, seconds: float = 1.0) -> int:
        """How many samples arrived in the last ``seconds`` (to see that it hears anything)."""
        with self._lock:
            return sum(1 for _, stamp, _ in self._events if stamp > now_ns - seconds * NS)

    def features(self, now_ns: int) -> np.ndarray:
        """The feature row at ``now_ns``; forgets what no window reaches any more."""
        with self._lock:
            while self._events and self._events[0][1] <= now_ns - self._keep_ns:
                self._events.popleft()
            held = list(self._events)
        return extract(held, np.array([now_ns]), self.spec)[0]


@dataclass
class Alarm:
    target: str
    started: bool  # True: a fault began; False: it ended
    step: int
    residual: float
    threshold: float


class Residuals:
    """Smoothed residuals of one target against its threshold."""

    def __init__(self, target: str, threshold: float) -> None:
        self.target, self.threshold = target, threshold
        self.level: float | None = None
        self.step = 0
        self.active = False
        self._streak = 0

    def update(self, measured: float, predicted: float) -> Alarm | None:
        residual = measured - predicted
        self.level = (
            residual if self.level is None else SMOOTHING * residual + (1 - SMOOTHING) * self.level
        )
        self.step += 1
        beyond = abs(self.level) > self.threshold
        self._streak = self._streak + 1 if beyond != self.active else 0
        if self._streak >= HOLD:
            self.active, self._streak = beyond, 0
            return Alarm(self.target, beyond, self.step, self.level, self.threshold)
        return None
