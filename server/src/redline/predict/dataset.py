"""Training and test data from recordings: at each time step (1 s) of each measured segment, the
features of the communication up to then (`redline.predict.features`) and what the component's
process used over that step (CPU %, RSS), grouped by execution and parameter set so that
cross-validation never splits neighbouring time steps of one run between training and test.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from redline.predict.features import IN, NS, WINDOWS, Event, FeatureSpec, extract, spec_for
from redline.recording.disturbance import recording_disturbances, threshold
from redline.recording.format import HOST_PROCESS, META_HOST, OWN_PROCESS, canonical_params
from redline.recording.reader import Recording, RecordingError, Segment, read_recording

#: what a model predicts: the monitor's counters of one component process
TARGETS = ("cpu_percent", "rss_bytes")
STEP_S = 1.0
#: the driver's actions whose key is one the component receives (a query is answered by it)
SENDING_ACTIONS = ("Publish", "FixedRate", "Query", "Replay")
#: a key the component sends on is one of its responses when, at every step at which it had
#: received anything in the last second, it had sent on that key within this many seconds:
#: `redline watch` alarms when it stops while traffic still comes in (a stall its CPU hides)
RESPONSE_WINDOW_S = 2.0
#: steps with incoming traffic that a key must have answered, at least, to count as a response
RESPONSE_MIN_STEPS = 10


class DataError(ValueError):
    """Data a model cannot be made from or applied to; the message says what is wrong."""


@dataclass
class Run:
    """One recording, read for learning."""

    path: Path
    events: list[Event]
    received: set[str]
    segments: list[Segment]  # the measured ones (warm-up phases left out)
    samples: dict[str, list[tuple[int, dict[str, float]]]]  # process -> (t_ns, values)
    #: measured segments another process's load disturbed, with why (case, phase, params)
    disturbed: dict[tuple[str, str, str], str] = field(default_factory=dict)
    #: the host's samples and Redline's own (`HOST_PROCESS`, `OWN_PROCESS`), and the host's
    #: cores: what else used the host at each step of a replay (`redline.predict.replay`)
    context: dict[str, list[tuple[int, dict[str, float]]]] = field(default_factory=dict)
    cores: int = 0


@dataclass
class Dataset:
    spec: FeatureSpec
    process: str
    x: np.ndarray
    y: dict[str, np.ndarray]
    groups: np.ndarray  # "file#segment" per row
    times: np.ndarray
    sources: list[str] = field(default_factory=list)
    left_out: list[str] = field(default_factory=list)  # disturbed segments, with why
    #: the keys the component answered on at every step it received traffic (`responses`)
    responses: tuple[str, ...] = ()


def read_run(path: str | Path) -> Run:
    """A recording's traffic, the keys the driver sent to the component, its measured segments
    and its processes' counter samples; DataError when there is nothing to learn from."""
    try:
        recording: Recording = read_recording(path, strict=False, events=True)
    except (OSError, RecordingError) as exc:
        raise DataError(f"{path}: {exc}") from None
    if recording.problem and not recording.markers:
        raise DataError(f"{path}: not a readable recording ({recording.problem})")
    events = recording.events or []
    if not events:
        raise DataError(f"{path}: the recording holds no traffic: nothing to learn from")
    received = {
        str(report["key"])
        for report in recording.driver
        if report.get("action") in SENDING_ACTIONS and report.get("key")
    }
    segments = [s for s in recording.segments() if not s.warmup]
    samples: dict[str, list[tuple[int, dict[str, float]]]] = {}
    context: dict[str, list[tuple[int, dict[str, float]]]] = {}
    for sample in recording.counters:
        process = sample.get("process", "")
        if not isinstance(sample.get("values"), dict):
            continue
        into = context if process in (HOST_PROCESS, OWN_PROCESS) else samples
        into.setdefault(process, []).append((int(sample["t_ns"]), sample["values"]))
    if not samples:
        raise DataError(f"{path}: no component process was monitored")
    disturbed = recording_disturbances(recording.series_samples(), threshold())
    given = str(recording.metadata.get(META_HOST, {}).get("cpu_cores", ""))
    cores = int(given) if given.isdigit() else 0
    return Run(Path(path), events, received, segments, samples, dict(disturbed), context, cores)


def component_process(runs: Sequence[Run], process: str | None) -> str:
    """``process``, checked; or the one component process the runs have in common."""
    common = set.intersection(*(set(run.samples) for run in runs))
    if process is not None:
        if process not in common:
            raise DataError(
                f"process {process!r} is not monitored in every recording "
                f"(all have: {', '.join(sorted(common)) or 'none'})"
            )
        return process
    if len(common) != 1:
        raise DataError(
            f"choose the process to model (--process): the recordings have "
            f"{', '.join(sorted(common)) or 'no process in common'}"
        )
    return next(iter(common))


def step_targets(
    samples: list[tuple[int, dict[str, float]]],
    times: np.ndarray,
    counters: Sequence[str] = TARGETS,
) -> dict[str, np.ndarray]:
    """Per target (or other counter), the mean of the samples in (t - step, t]; NaN where there
    is none."""
    stamps = np.array([t for t, _ in samples], dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    stamps = stamps[order]
    out = {}
    for target in counters:
        values = np.array([float(samples[i][1].get(target, np.nan)) for i in order])
        totals = np.concatenate(([0.0], np.cumsum(np.nan_to_num(values))))
        valid = np.concatenate(([0], np.cumsum(~np.isnan(values))))
        hi = np.searchsorted(stamps, times, side="right")
        lo = np.searchsorted(stamps, times - int(STEP_S * NS), side="right")
        count = valid[hi] - valid[lo]
        total = totals[hi] - totals[lo]
        out[target] = np.divide(total, count, out=np.full(len(times), np.nan), where=count > 0)
    return out


def dataset(
    runs: Sequence[Run],
    process: str | None = None,
    spec: FeatureSpec | None = None,
    windows: Sequence[float] = WINDOWS,
    keep: Callable[[Segment], bool] | None = None,
    keys: Callable[[str], bool] | None = None,
    keep_disturbed: bool = False,
    received_only: bool = False,
) -> Dataset:
    """The rows of every measured segment of ``runs`` that ``keep`` keeps (a step each second
    from the segment's first full second), features by ``spec`` (by default: every key the runs
    saw that ``keys`` keeps, received or sent); rows without a counter sample are left out, and
    so are segments another process's load disturbed (unless ``keep_disturbed``: the component's
    usage there is not what its traffic alone makes it, and one such segment in the validation
    data would widen the run-time alarm's threshold several times; `Dataset.left_out` names
    them). ``received_only``: features of the keys the component receives only."""
    if not runs:
        raise DataError("no recordings given")
    chosen = component_process(runs, process)
    if spec is None:
        everything = [e for run in runs for e in run.events if keys is None or keys(e[0])]
        spec = spec_for(everything, set().union(*(run.received for run in runs)), windows)
        if received_only:
            spec = FeatureSpec(tuple(c for c in spec.channels if c[1] == IN), spec.windows)
            if not spec.channels:
                raise DataError("the driver sent the component nothing: no feature it receives")
    xs, groups, times_all, run_times = [], [], [], []
    ys: dict[str, list[np.ndarray]] = {t: [] for t in TARGETS}
    left_out: list[str] = []
    for number, run in enumerate(runs):
        for segment in run.segments:
            if keep is not None and not keep(segment):
                continue
            name = f"{segment.case}/{segment.phase}/{sorted(segment.params.items())}"
            why = run.disturbed.get((segment.case, segment.phase, canonical_params(segment.params)))
            if why and not keep_disturbed:
                left_out.append(f"{run.path}: {name}: {why}")
                continue
            step = int(STEP_S * NS)
            times = np.arange(segment.begin_ns + step, segment.end_ns + 1, step, dtype=np.int64)
            if not len(times):
                continue
            targets = step_targets(run.samples[chosen], times)
            sampled = ~np.isnan(targets["cpu_percent"])
            if not sampled.any():
                continue
            xs.append(extract(run.events, times[sampled], spec))
            for target in TARGETS:
                ys[target].append(targets[target][sampled])
            groups += [f"{number}#{name}"] * int(sampled.sum())
            times_all.append(times[sampled])
            run_times.append((run, times[sampled]))
    if not xs:
        raise DataError(
            "the recordings have no measured segment with counter samples of "
            f"process {chosen!r}: nothing to learn from"
            + (
                f" ({len(left_out)} left out, disturbed by other load: {left_out[0]}"
                + (" ..." if len(left_out) > 1 else "")
                + ")"
                if left_out
                else ""
            )
        )
    return Dataset(
        spec=spec,
        process=chosen,
        x=np.vstack(xs),
        y={t: np.concatenate(v) for t, v in ys.items()},
        groups=np.array(groups),
        times=np.concatenate(times_all),
        sources=[str(run.path) for run in runs],
        left_out=left_out,
        responses=responses(run_times, keys),
    )


def in_window(stamps: np.ndarray, times: np.ndarray, seconds: float) -> np.ndarray:
    """How many of the sorted ``stamps`` lie in (t - seconds, t], for each t of ``times``."""
    hi = np.searchsorted(stamps, times, side="right")
    return hi - np.searchsorted(stamps, times - int(seconds * NS), side="right")


def responses(
    rows: Sequence[tuple[Run, np.ndarray]], keys: Callable[[str], bool] | None = None
) -> tuple[str, ...]:
    """The keys the component sent on within `RESPONSE_WINDOW_S` of every step (of ``rows``:
    each run with its steps' times) at which it had received anything in the last second,
    over at least `RESPONSE_MIN_STEPS` such steps."""
    by_run = []
    for run, times in rows:
        stamps: dict[str, list[int]] = {}
        for key, stamp, _ in run.events:
            if keys is None or keys(key):
                stamps.setdefault(key, []).append(stamp)
        by_run.append((run, times, stamps))
    candidates = {k for run, _, stamps in by_run for k in stamps if k not in run.received}
    busy_steps = 0
    for run, times, stamps in by_run:
        inbound = np.sort(
            np.array([t for k, v in stamps.items() if k in run.received for t in v], np.int64)
        )
        busy = in_window(inbound, times, STEP_S) > 0
        busy_steps += int(busy.sum())
        for key in list(candidates):
            sent = np.sort(np.array(stamps.get(key, []), np.int64))
            if not (in_window(sent, times[busy], RESPONSE_WINDOW_S) > 0).all():
                candidates.discard(key)
    return tuple(sorted(candidates)) if busy_steps >= RESPONSE_MIN_STEPS else ()
