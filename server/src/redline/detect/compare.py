"""Offline comparison of recordings, for CI without a server (the paper's Jenkins flow).

Baseline and candidate are each one or more recordings; the samples of every series are pooled
per side (the paper: "the individual measurements ... of potentially multiple executions form an
observation") and judged exactly as the service's KS judges them: `redline.detect.verdict`'s
`judge_series` with `KolmogorovSmirnov` (the KS test, then the counter's absolute floor), the
host-wide series and the user/system split of CPU left out (`redline.detect.counters`); a
component's CPU judged per unit of work at the host's speed where each side holds enough
values of it for KS to decide (five recordings a side at its alpha of 0.01), else by its
share's samples (`_one_cpu_figure`). Results
are grouped into one verdict per test case × phase × parameter set. A series only one side holds
is "not enough data" saying which side (`ONLY_IN`): never a silent pass. In a segment the host
was busy in (other load) in every recording of a side, only what the component holds and other
load does not move (memory, files: `redline.detect.counters.is_held`; not its threads and
address space) is judged, as the service judges it; the segment says so and cannot pass
(`BUSY_PART`); busy in some recordings only, it is judged on the others. Reading the files is
the only I/O here.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
from redline.detect.comparison import (
    BUSY_PART,
    NOT_JUDGED_BUSY,
    ONLY_IN,
    WHY_DRIVER,
    WHY_PROCESS,
    CompareError,
    Comparison,
    RecordedSeries,
    Segment,
    SegmentVerdict,
    SeriesVerdict,
)
from redline.detect.count_rate import CountRate
from redline.detect.counters import (
    CONTEXT_COUNTERS,
    LEVELS,
    SHARE,
    driver_metric,
    holds,
    is_count,
    is_held,
    is_load,
    judged_among,
    kind,
    left_out,
)
from redline.detect.methods import KolmogorovSmirnov
from redline.detect.relative_change import RelativeChange
from redline.detect.result import NO_CHANGE, Detection, not_enough
from redline.detect.verdict import TOO_FEW, judge_series
from redline.recording import (
    Recording,
    RecordingError,
    SeriesKey,
    read_recording,
)
from redline.recording.disturbance import DEFAULT_THRESHOLD, recording_disturbances
from redline.recording.driver import CPU_REFS_PER_OP


def _label(recording: Recording) -> str:
    title = recording.run.get("revision_title", "")
    return f"{recording.path.name} ({title})" if title else recording.path.name


def load_side(
    paths: Sequence[str | Path],
    side: str,
    context: Collection[str] = CONTEXT_COUNTERS,
    busy_limit: float = DEFAULT_THRESHOLD,
) -> tuple[RecordedSeries, ...]:
    """Read a side's recordings strictly, keeping the series a verdict is asked of
    (`redline.detect.counters`) and noting the segments the host was busy in (other load over
    ``busy_limit``, % of a core); CompareError names the first file that is unusable."""
    if not paths:
        raise CompareError(f"no {side} recording given")
    loaded = []
    for given in paths:
        path = Path(given)
        if not path.is_file():
            raise CompareError(f"{side} recording {path}: no such file")
        try:
            recording = read_recording(path, strict=True)
        except RecordingError as exc:
            raise CompareError(f"{side} recording {path}: {exc}") from None
        except OSError as exc:
            raise CompareError(f"{side} recording {path}: {exc.strerror or exc}") from None
        everything = recording.series_timeline()
        busy = recording_disturbances(
            {key: [value for _, value in points] for key, points in everything.items()}, busy_limit
        )
        # the judged series, and the driver's loads that its counts are rated out of; in a
        # segment the host was busy in only what the component holds: the rest is not its own
        # of a CPU share and its CPU per unit of work both: `compare_sides` picks one
        asked = set(judged_among(everything, context, LEVELS))
        out = left_out(everything, busy)  # a busy segment's, but what the component holds
        timeline = {
            key: points
            for key, points in everything.items()
            if (key in asked or is_load(key.process, key.counter)) and key not in out
        }
        loaded.append(
            RecordedSeries(path=path, label=_label(recording), timeline=timeline, disturbed=busy)
        )
    return tuple(loaded)


def pooled(side: Sequence[RecordedSeries]) -> dict[SeriesKey, np.ndarray]:
    """Every sample of each series over all of a side's recordings."""
    parts: dict[SeriesKey, list[float]] = {}
    for recorded in side:
        for key, points in recorded.timeline.items():
            parts.setdefault(key, []).extend(value for _, value in points)
    return {key: np.asarray(values, dtype=np.float64) for key, values in parts.items()}


def _segment(key: SeriesKey) -> Segment:
    return key.case, key.phase, key.params


def _judge(
    key: SeriesKey, base: dict[SeriesKey, np.ndarray], cand: dict[SeriesKey, np.ndarray]
) -> Detection:
    """A process counter by KS on its samples; a driver's count of rare events as a rate out of
    its total (`CountRate`); a driver's other metric, one value per recording, by the change of
    its median (`RelativeChange`)."""
    if is_count(key.process, key.counter):
        stem = key.counter.rpartition(":")[0]
        metric = driver_metric(key.process, key.counter)
        totals = [
            replace(key, counter=f"{stem}:{of}" if stem else of)
            for of in (metric.of if metric else ())
        ]
        total = next((t for t in totals if t in base and t in cand), None)
        if total is None:
            return not_enough("count_rate", "nothing says what these events are counted out of")
        return CountRate().compare(
            float(base[key].sum()),
            float(base[total].sum()),
            float(cand[key].sum()),
            float(cand[total].sum()),
        )
    if kind(key.process) != "counter":
        return judge_series(RelativeChange(), key.counter, base[key], cand[key])
    return judge_series(KolmogorovSmirnov(), key.counter, base[key], cand[key])


#: The fewest recordings a side from which a change in what a component does (its CPU, its
#: rates; not what it holds) can be told from run-to-run noise: one run's samples share that
#: run's level, so KS over them answers for the run, not the code (a trial: unchanged code
#: failed 9 of 15 comparisons of one recording against one, cpu_percent +13.6 %, p 0.0066, and
#: +37.3 % between two runs of the same commit). With n a side a change must also show in every
#: recording (`_across_runs`), which unchanged code does by chance once in C(2n, n) per
#: direction: 1 in 20 at 3, 252 at 5.
MIN_RUNS = 3


def _runs(side: Sequence[RecordedSeries]) -> dict[SeriesKey, list[float]]:
    """Each series' median in each recording of a side."""
    found: dict[SeriesKey, list[float]] = {}
    for recorded in side:
        for key, points in recorded.timeline.items():
            if points:
                found.setdefault(key, []).append(float(np.median([v for _, v in points])))
    return found


def _across_runs(
    verdict: SeriesVerdict, base: dict[SeriesKey, list[float]], cand: dict[SeriesKey, list[float]]
) -> SeriesVerdict:
    """A change KS found in the pooled samples of what a component does, kept only where the
    recordings can tell it from run-to-run noise: at least `MIN_RUNS` a side ("too few" below
    that: undecided, never a failure), every candidate recording beyond every baseline one
    (else no change: the runs overlap). What the component holds (memory, threads, files)
    barely moves from run to run and is judged on its samples as before."""
    key, found = verdict.key, verdict.result
    if not found.flagged or kind(key.process) != "counter" or holds(key.process, key.counter):
        return verdict
    before, after = base.get(key, []), cand.get(key, [])
    p_value = found.p_value if found.p_value is not None else math.nan
    if min(len(before), len(after)) < MIN_RUNS:
        reason = (
            f"{TOO_FEW} {len(before)} and {len(after)} recording(s) a side (KS on their "
            f"samples: effect {found.effect:+.1%}, p {p_value:.2g}); a run's samples share "
            f"its level, so fewer than {MIN_RUNS} a side cannot tell a change from run-to-run "
            "noise: record more executions a side (5 and 5 suffice)"
        )
        return replace(verdict, result=not_enough(found.method, reason))
    up = found.direction == "increase"
    apart = min(after) > max(before) if up else max(after) < min(before)
    if apart:
        return verdict
    reason = (
        f"KS on the pooled samples: effect {found.effect:+.1%}, p {p_value:.2g}; but the "
        f"recordings overlap (baseline {min(before):.4g}-{max(before):.4g}, candidate "
        f"{min(after):.4g}-{max(after):.4g}): run-to-run noise, not a change of every run"
    )
    return replace(verdict, result=replace(found, verdict=NO_CHANGE, reason=reason))


def _verdict(
    key: SeriesKey, base: dict[SeriesKey, np.ndarray], cand: dict[SeriesKey, np.ndarray]
) -> SeriesVerdict:
    return SeriesVerdict(
        key=key,
        result=_judge(key, base, cand),
        baseline_mean=float(np.mean(base[key])),
        candidate_mean=float(np.mean(cand[key])),
        baseline_n=int(base[key].size),
        candidate_n=int(cand[key].size),
    )


def _one_sided(key: SeriesKey, held: dict[SeriesKey, np.ndarray], side: str) -> SeriesVerdict:
    """The verdict of a series only ``side`` holds (``held``: that side's samples)."""
    why = WHY_DRIVER if kind(key.process) in ("driver", "recorder") else WHY_PROCESS
    if is_count(key.process, key.counter):
        method = CountRate.name
    else:
        method = RelativeChange.name if kind(key.process) != "counter" else KolmogorovSmirnov.name
    values = held[key]
    mean, size = (float(np.mean(values)) if values.size else math.nan), int(values.size)
    first = side == "baseline"
    return SeriesVerdict(
        key=key,
        result=not_enough(method, ONLY_IN.format(side=side, why=why)),
        baseline_mean=mean if first else math.nan,
        candidate_mean=math.nan if first else mean,
        baseline_n=size if first else 0,
        candidate_n=0 if first else size,
        only_in=side,
    )


def _busy(recorded: Sequence[RecordedSeries]) -> dict[Segment, str]:
    """The segments the host was busy in, in a recording of either side, with the first
    recording that said so."""
    found: dict[Segment, str] = {}
    for side in recorded:
        for ident, why in side.disturbed.items():
            found.setdefault(ident, f"{side.path.name}: {why}")
    return found


def _held_only(verdicts: Sequence[SeriesVerdict]) -> bool:
    return all(is_held(v.key.process, v.key.counter) for v in verdicts)


def decisive_values(alpha: float) -> int:
    """The fewest values a side for which KS can find a change at ``alpha``: with n a side that
    do not overlap, its exact two-sided p is 2 / C(2n, n) (0.33 at 2, 0.1 at 3, 0.029 at 4,
    0.0079 at 5)."""
    n = 1
    while 2 / math.comb(2 * n, n) >= alpha:
        n += 1
    return n


def _one_cpu_figure(
    keys: Collection[SeriesKey],
    base: dict[SeriesKey, np.ndarray],
    cand: dict[SeriesKey, np.ndarray],
) -> set[SeriesKey]:
    """``keys`` with one of each process's two CPU figures in a segment (as
    `redline.detect.counters.one_cpu_figure` keeps one): its
    CPU per unit of work at the host's speed, one value a recording, where both sides hold
    enough of it for KS to decide (`decisive_values`), else its share's samples. Decided per
    segment and by what each side holds: a side without the host's reference (an older agent)
    or with a busy recording's segment left out has too few, and its share is judged."""
    need = decisive_values(KolmogorovSmirnov().alpha)

    def per_unit_decides(key: SeriesKey) -> bool:
        figure = replace(key, counter=CPU_REFS_PER_OP)
        return all(figure in side and side[figure].size >= need for side in (base, cand))

    shares = {key for key in keys if key.counter == SHARE}
    per_unit = {key for key in keys if key.counter == CPU_REFS_PER_OP}
    dropped = {key for key in shares if per_unit_decides(key)} | {
        key
        for key in per_unit
        if replace(key, counter=SHARE) in shares and not per_unit_decides(key)
    }
    return set(keys) - dropped


def compare_sides(
    baseline: tuple[RecordedSeries, ...], candidate: tuple[RecordedSeries, ...]
) -> Comparison:
    """Judge every series both sides hold, and answer "not enough data" for each that only
    one side holds (`ONLY_IN`) outside the segments the host was busy in; CompareError when
    they hold none in common."""
    base, cand = pooled(baseline), pooled(candidate)
    every = _one_cpu_figure(
        {key for key in base.keys() | cand.keys() if not is_load(key.process, key.counter)},
        base,
        cand,
    )
    common = sorted(key for key in every if key in base and key in cand)
    if not common:
        raise CompareError(
            f"the baseline and the candidate have no series in common (baseline: "
            f"{len(base)} series, candidate: {len(cand)}; compare recordings of "
            f"the same test cases, phases and parameter sets)"
        )
    by_segment: dict[Segment, list[SeriesVerdict]] = {}
    runs = _runs(baseline), _runs(candidate)
    for key in common:
        found = _across_runs(_verdict(key, base, cand), *runs)
        by_segment.setdefault(_segment(key), []).append(found)
    busy = _busy(baseline + candidate)
    # a busy segment whose CPU a side's quiet recordings measured is judged whole; one where
    # both sides hold only what the component holds, in part; one neither, not at all
    whole = {ident for ident, found in by_segment.items() if not _held_only(found)}
    notes = {
        ident: (BUSY_PART if ident in by_segment else NOT_JUDGED_BUSY).format(why=why)
        for ident, why in busy.items()
        if ident not in whole
    }
    for key in sorted(every - set(common)):
        ident = _segment(key)
        if ident in notes and not is_held(key.process, key.counter):
            continue  # not measured in quiet: the segment's note says so
        side, held = ("baseline", base) if key in base else ("candidate", cand)
        by_segment.setdefault(ident, []).append(_one_sided(key, held, side))
    segments = [
        SegmentVerdict(*ident, series=tuple(found), note=notes.get(ident, ""))
        for ident, found in by_segment.items()
    ]
    segments += [
        SegmentVerdict(*ident, note=note)
        for ident, note in sorted(notes.items())
        if ident not in by_segment
    ]
    segments.sort(key=lambda s: (s.case, s.phase, s.params))
    return Comparison(baseline=baseline, candidate=candidate, segments=tuple(segments))


def compare_files(
    baseline: Sequence[str | Path],
    candidate: Sequence[str | Path],
    context: Collection[str] = CONTEXT_COUNTERS,
    busy_limit: float = DEFAULT_THRESHOLD,
) -> Comparison:
    """Read both sides and compare them (raises CompareError on bad input); ``context``: the
    counters not judged (by default the user/system split of CPU, whose total is judged);
    ``busy_limit``: the other load (% of a core) over which a segment was disturbed."""
    return compare_sides(
        load_side(baseline, "baseline", context, busy_limit),
        load_side(candidate, "candidate", context, busy_limit),
    )
