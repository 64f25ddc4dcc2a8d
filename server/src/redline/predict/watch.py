"""Run-time fault detection with a resource model: the live counterpart of the features' input,
and the residual between measured and predicted usage, smoothed, against a threshold calibrated
on validation data (Wienke & Wrede, Section 6; `redline watch` wires it to zenoh and /proc).

`EventWindow` keeps what a live subscriber heard in the longest window, and extracts features with
the very function training used (`redline.predict.features.extract`). `Residuals` smooths the
residual (an exponentially weighted mean) and raises an alarm once it stays beyond the threshold
for `HOLD` steps in a row; the alarm ends when it has been back within for as long.

A process is judged by how its usage moves from where it stood, not only by its level: each
target's residual is also taken from its median over the first `ANCHOR_STEPS` judged steps (the
process's offset), and an alarm starts when that moved residual, smoothed, stays beyond the
threshold, or when the residual itself stays beyond `GROSS` times the threshold. Two processes of
the same code differ for the same traffic by more than a model's error: a fresh objectbuilder's
RSS stood 1.6 MB (5 %) below its training run's, and its CPU can settle 7.5 % of a core lower (a
cheaper hand-over of the GIL between its threads), close to what a stall takes away; judged by
level alone, both alarmed on clean traffic. A fault shows as a move (a thread starts spinning, the
workers stall, memory keeps growing); one present before watching began is seen only when gross
(a busy thread: tens of % of a core), and the offset is reported for a person to judge. The CPU
offset then follows the process's clean steps (`DRIFTING`): its cost for the same traffic
wanders, within a run and between hosts, by more than a threshold.

A step in which the host was busy with other work (`Contention`) says nothing of the component's
CPU: on 2 cores the same traffic cost a clean objectbuilder 12 % of a core more while a
neighbour spun, beyond its threshold of 10. Its CPU residual is left out, as the agent leaves a
disturbed phase out of the verdicts (`redline.recording.disturbance`), and the step says so.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from statistics import median

import numpy as np
from redline.predict.dataset import TARGETS
from redline.predict.features import NS, Event, FeatureSpec, extract
from redline.recording.disturbance import other_load
from redline.recording.format import HOST_PROCESS, OWN_PROCESS

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
#: judged steps whose median residual is the process's offset (the moves are judged after them)
ANCHOR_STEPS = 10
#: the residual's own level alarms beyond this many times the threshold, whatever the offset
GROSS = 3.0
#: targets whose offset then follows the process as it wanders, on the steps outside an alarm
#: whose move stays within the threshold: the objectbuilder's CPU for the same traffic stood
#: 0.68-0.95 of a same-host model's prediction in 30-step stretches of one clean 5-minute run,
#: and 1.5-1.8 times the committed model's (learnt on another VM), the gap growing with the
#: load; a fixed offset, taken off at one stretch's level, made a CI run's clean minute alarm
#: at step 40 (+27.9 against 22.6). Memory's offset stays fixed: a leak is a slow rise, which
#: an offset that followed it would hide
DRIFTING = frozenset({"cpu_percent"})
#: steps a drifting offset takes to follow a move (the weight of each step's residual in it is
#: one over this): a fault's move is beyond the threshold within a step or two, and is judged
DRIFT_STEPS = 30
#: an offset within this share of the threshold is the model's own error, not the process's
#: level: it is not taken off (taking off -2.9 % of a core, measured over the first steps, made
#: a later +6.6 % a move of +9.5 beyond a threshold of 8.3 in a clean CI run, and shrank what a
#: stall takes away by as much)
OFFSET_FLOOR = 0.5
#: targets another process's load moves: their residual is left out of a step the host was
#: busy in (memory is the component's own, whatever else runs)
CONTENDED = frozenset({"cpu_percent"})
#: targets whose fall below the prediction is no fault where the model knows the component's
#: responses: `Silence` judges a stall, the fault a fall stood for, within 5 s (CPU took 13-16).
#: A clean objectbuilder's CPU fell to 0.38-0.57 of the prediction for 30 s in a live watch, what
#: it heard and answered unchanged, other load up by 12 % of a core (a move of -9.9 against a
#: threshold of 9.1, 2026-12-07); a CI run's clean minute alarmed so (-9.3 against 7.7); every
#: false CPU alarm on clean traffic before the host's contention was told was a fall
#: (docs/prediction.md). Memory's falls are judged, and CPU's where no response is known
RISING = frozenset({"cpu_percent"})
#: steps whose other load is the host's usual: a step beyond their median by the disturbance
#: threshold is busy (a robot's other components may use cores throughout; a burst is judged)
USUAL_STEPS = 30


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

    def _forget(self, now_ns: int) -> None:
        """Drop what no window reaches any more (the lock held)."""
        while self._events and self._events[0][1] <= now_ns - self._keep_ns:
            self._events.popleft()

    def heard(self, now_ns: int, seconds: float = 1.0, key: str | None = None) -> int:
        """How many samples arrived in the last ``seconds`` (of ``key``, else of every key)."""
        with self._lock:
            self._forget(now_ns)
            return sum(
                1
                for k, stamp, _ in self._events
                if stamp > now_ns - seconds * NS and (key is None or k == key)
            )

    def features(self, now_ns: int) -> np.ndarray:
        """The feature row at ``now_ns``; forgets what no window reaches any more."""
        with self._lock:
            self._forget(now_ns)
            held = list(self._events)
        return extract(held, np.array([now_ns]), self.spec)[0]


@dataclass
class Alarm:
    target: str
    started: bool  # True: a fault began; False: it ended
    step: int
    residual: float  # the smoothed residual judged: its level when gross, else its move
    threshold: float
    offset: float | None = None  # the process's offset (None while it is being measured)


@dataclass(frozen=True)
class Step:
    """One step of a watch, live or replayed, as `redline watch --json` prints it."""

    t_ns: int
    warming: bool
    heard: int
    answered: dict[str, int]
    measured: dict[str, float]
    predicted: dict[str, float]
    #: what else used the host in the step, in % of one core (None: not known), and whether
    #: that made it busy (`Contention`)
    other_cpu: float | None = None
    host_busy: bool = False

    def line(self) -> dict:
        return {
            "t": self.t_ns / 1e9,
            "warming": self.warming,
            "heard": self.heard,
            "answered": self.answered,
            "measured": self.measured,
            "predicted": self.predicted,
            "other_cpu_percent": self.other_cpu,
            "host_busy": self.host_busy,
        }


def other_cpu(host: Mapping[str, float], used: float, cores: int) -> float | None:
    """What else used the host in a step, in % of one core, as the agent tells a disturbed phase
    (`redline.recording.disturbance.other_load`): the host's busy and stolen CPU (``host``, % of
    all CPUs, as `HostSampler` gives them) times its ``cores``, less what the component's
    processes and Redline's own ``used`` (% of one core); None where it cannot be told."""
    busy, stolen = host.get("cpu_percent", math.nan), host.get("cpu_steal_percent", 0.0)
    if not (math.isfinite(busy) and math.isfinite(used)):
        return None
    stolen = stolen if math.isfinite(stolen) else 0.0
    return other_load(
        {
            (HOST_PROCESS, "cpu_percent"): [busy],
            (HOST_PROCESS, "cpu_steal_percent"): [stolen],
            (OWN_PROCESS, "cpu_percent"): [used],
        },
        cores,
    )


class Contention:
    """Whether the host was busy with other work in a step: its other load (the host's CPU less
    the component's and the watcher's, in % of one core) beyond the median of the previous
    `USUAL_STEPS` steps' by more than ``limit`` (the agent's disturbance threshold, 30 % of a
    core by default). A level that stays becomes the usual within half as many steps."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self.usual: float | None = None  # the median the last step was judged against
        self._recent: deque[float] = deque(maxlen=USUAL_STEPS)

    def busy(self, other: float | None) -> bool:
        if other is None:
            return False
        self.usual = median(self._recent) if self._recent else other
        self._recent.append(other)
        return other - self.usual > self.limit


class Residuals:
    """Smoothed residuals of one target against its threshold, judged by their move from the
    process's offset (once `ANCHOR_STEPS` clean steps in a row, neither gross nor in an alarm,
    have measured it) and by their level against `GROSS` times the threshold. ``falls``: whether
    a residual below the prediction can be a fault (else only a rise is judged)."""

    def __init__(self, target: str, threshold: float, falls: bool = True) -> None:
        self.target, self.threshold, self.falls = target, threshold, falls
        self.level: float | None = None  # the smoothed residual
        self.moved: float | None = None  # the smoothed residual less the offset
        self.offset: float | None = None
        self.step = 0
        self.busy_steps = 0  # steps left out, the host busy with other work
        self.active = False
        self._streak = 0
        self._first: list[float] = []

    @property
    def taken_off(self) -> float:
        """What the moves are measured from: the offset, unless it is within the model's error."""
        if self.offset is None or abs(self.offset) <= OFFSET_FLOOR * self.threshold:
            return 0.0
        return self.offset

    def _beyond(self, value: float, limit: float) -> bool:
        return value > limit or (self.falls and value < -limit)

    @staticmethod
    def _smooth(level: float | None, value: float) -> float:
        return value if level is None else SMOOTHING * value + (1 - SMOOTHING) * level

    def update(self, measured: float, predicted: float, busy: bool = False) -> Alarm | None:
        """Judge one step; ``busy``: the host was busy with other work, and a `CONTENDED`
        target's residual is left out (nothing of it moves: level, offset, streak)."""
        self.step += 1
        if busy and self.target in CONTENDED:
            self.busy_steps += 1
            return None
        residual = measured - predicted
        self.level = self._smooth(self.level, residual)
        gross = self._beyond(self.level, GROSS * self.threshold)
        if self.offset is None:
            # measured over clean steps in a row: a fault there would become the process's
            # level, and its end a move that never ends
            if gross or self.active:
                self._first.clear()
            else:
                self._first.append(residual)
                if len(self._first) == ANCHOR_STEPS:
                    self.offset = float(np.median(self._first))
        else:
            # the smoothed residual less the offset: smoothing is linear, so these are the
            # moves smoothed since the first step. Restarted at the offset, a burst in its first
            # step counted unsmoothed: a clean objectbuilder in a CI run alarmed on CPU at step 13,
            # three steps after its offset was measured (23.6 against a threshold of 22.6)
            self.moved = self.level - self.taken_off
        moved = self.moved is not None and self._beyond(self.moved, self.threshold)
        # until the offset is known, only a gross level alarms
        judged = self.level if gross or self.moved is None else self.moved
        beyond = gross or moved
        self._follow(residual)
        self._streak = self._streak + 1 if beyond != self.active else 0
        if self._streak >= HOLD:
            self.active, self._streak = beyond, 0
            return Alarm(self.target, beyond, self.step, judged, self.threshold, self.offset)
        return None

    def _follow(self, residual: float) -> None:
        """A `DRIFTING` target's offset moves a `DRIFT_STEPS`th of the way to ``residual`` (or
        of half the threshold, at most) when the step is clean: not in an alarm, its move within
        the threshold (a fault's move is beyond it after a few steps, and is not followed from
        then on). What it gives up: a rise slower than half the threshold per `DRIFT_STEPS`
        steps is followed, not judged."""
        if self.target not in DRIFTING or self.offset is None or self.moved is None:
            return
        if not self.active and abs(self.moved) <= self.threshold:
            # no step pulls it by more than half the threshold: a fault's first steps, still
            # within the threshold once smoothed, would pull it a 30th of the fault's size
            # each, delaying the alarm they start (+50 % of a core: 1.7 a step, unclipped)
            reach = OFFSET_FLOOR * self.threshold
            self.offset += float(np.clip(residual - self.offset, -reach, reach)) / DRIFT_STEPS


def trackers(metrics: Mapping[str, Mapping], responses: Sequence[str]) -> dict[str, Residuals]:
    """Each target's `Residuals` at its model's threshold; a `RISING` target's falls judged only
    where the model knows no response (then a fall is the only sign of a stall)."""
    return {
        target: Residuals(
            target, metrics[target]["threshold"], not (responses and target in RISING)
        )
        for target in TARGETS
    }


class Silence:
    """One of the component's responses (a key it answered on at every step of its training at
    which it received traffic) judged each step: silent when traffic came in during the last
    second and nothing went out on the key within `RESPONSE_WINDOW_S`. An alarm starts after
    `HOLD` silent steps in a row and ends after as many answered ones; a step without incoming
    traffic says nothing. What a stall shows when its CPU does not: a component whose workers
    stand still uses less CPU than it did, by less than a threshold set by the model's own noise
    may allow (docs/prediction.md), but it stops answering at once."""

    def __init__(self, key: str) -> None:
        self.key, self.target = key, f"silence:{key}"[:50]
        self.step = 0
        self.active = False
        self._streak = 0

    def update(self, received: int, answered: int) -> Alarm | None:
        """``received``: samples heard on the inputs in the last second; ``answered``: sent on
        the key within the response window. The alarm's residual is the unanswered samples."""
        self.step += 1
        if received <= 0:
            return None
        silent = answered == 0
        self._streak = self._streak + 1 if silent != self.active else 0
        if self._streak >= HOLD:
            self.active, self._streak = silent, 0
            return Alarm(self.target, silent, self.step, float(received if silent else 0), 0.0)
        return None


def judge_step(
    residuals: dict[str, Residuals],
    silences: list[Silence],
    measured: dict[str, float],
    predicted: dict[str, float],
    received: int,
    answered: dict[str, int],
    busy: bool = False,
) -> list[Alarm]:
    """One judged step, live or replayed: each target's residual, then each response's
    silence; the alarms it started or ended. ``busy``: the host was (`Contention`)."""
    alarms = [tracker.update(measured[t], predicted[t], busy) for t, tracker in residuals.items()]
    alarms += [silence.update(received, answered[silence.key]) for silence in silences]
    return [alarm for alarm in alarms if alarm is not None]
