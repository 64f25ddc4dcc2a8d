"""Measure detectors on a labelled corpus: ROC-AUC, precision, recall and F1.

Every build of every series but the first is one unit, judged as the service judges a new
revision: against the ``recent`` baseline (`redline.detect.baseline`), which depends on the
method's own earlier verdicts on the series, so the history is walked in order per method.
ROC-AUC ranks units by score (an abstention, "not enough data", scores 0); precision,
recall and F1 count a unit as flagged when the method's verdict, at its default threshold
and effect-size floor, is "change". Pure computation over a loaded `Corpus`.

A series whose label names the ``process`` it measures (a test driver's metric: ``driver``) is
judged as the service judges it (`redline.detect.counters`): a series the service asks no
verdict of (a load the driver delivered, a round trip's p99) is no unit; a flag is an alarm only
towards the worse (a shorter round trip is a change, not a regression); counts of rare events
(timeouts) are judged by `CountRate` out of their totals, whatever the method. Series that name
no process (SAP's, corpus 2's process counters) count a flag either way, as before.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Iterator, Mapping, Sequence

import numpy as np
from redline.detect.baseline import DEFAULT_WINDOW, lookback, recent_depth, take_recent
from redline.detect.changepoint import EDivisive
from redline.detect.changepoint_f1 import MARGIN, binary_segmentation, f_measure
from redline.detect.confirmation import DEFAULT_CONFIRM_REVISIONS, HELD, LOOKBACK, hold
from redline.detect.corpus import (
    Corpus,
    Measures,
    SeriesLabel,
    Unit,
    measures,
    series_builds,
    total_of,
)
from redline.detect.corpus import counter_of as counter_of  # where benchmarks import it
from redline.detect.count_rate import CountRate
from redline.detect.execution_shift import values_for
from redline.detect.methods import Detector
from redline.detect.registry import CHANGE_POINT_METHOD, DEFAULT_METHOD, EVALUATED
from redline.detect.result import Detection, direction_of, not_enough
from redline.detect.scores import MethodScores, Outcome, summarize
from redline.detect.suspected import BEFORE, LevelBefore, after_flag
from redline.detect.verdict import judge_series

#: Called with (series done, series in all) as an evaluation walks a corpus.
Progress = Callable[[int, int], None]


def change_sizes(corpus: Corpus) -> dict[tuple[str, int], float]:
    """Each labelled change's size as the data show it, by (series, first build after it): the
    relative move of the median of the build medians from the builds since the previous change
    (or the series' start) to the builds up to the next change (or its end), so one noisy build
    does not decide it and a second change does not count in the first one's size."""
    sizes = {}
    for series, label, builds in series_builds(corpus):
        changes = label.change_builds
        if not changes:
            continue
        medians = [(build, float(np.median(np.concatenate(runs)))) for build, runs in builds]
        bounds = [-math.inf, *changes, math.inf]
        for index, change in enumerate(changes):
            before = [m for b, m in medians if bounds[index] <= b < change]
            after = [m for b, m in medians if change <= b < bounds[index + 2]]
            if not before or not after:
                continue
            level, moved = float(np.median(before)), float(np.median(after))
            sizes[(series, change)] = abs(moved - level) / abs(level) if level else math.inf
    return sizes


def snapped(changes: Sequence[int], builds: Sequence[int]) -> set[int]:
    """Each labelled change at the first build the series has at or after it (a label may name
    a build the series skipped); one past the series' end is dropped."""
    ordered = sorted(builds)
    found = set()
    for change in changes:
        index = bisect.bisect_left(ordered, change)
        if index < len(ordered):
            found.add(ordered[index])
    return found


def rate_verdict(
    events: Sequence[np.ndarray], totals: Sequence[np.ndarray | None], k: int, depth: int
) -> Detection:
    """`CountRate` on build ``k``'s events against the ``depth`` builds before it, each side
    summed over its executions, out of the totals of the same builds (as the worker judges)."""
    judge = CountRate()
    sides = (range(k - depth, k), range(k, k + 1))
    if any(totals[j] is None for side in sides for j in side):
        return not_enough(judge.name, "nothing says what these events are counted out of")

    def summed(values: Sequence[np.ndarray | None], side: range) -> float:
        return sum(float(np.sum(np.asarray(values[j]))) for j in side)

    (base, cand) = sides
    return judge.compare(
        summed(events, base), summed(totals, base), summed(events, cand), summed(totals, cand)
    )


def walk(
    detector: Detector,
    corpus: Corpus,
    window: int = DEFAULT_WINDOW,
    progress: Progress | None = None,
    wait: int = DEFAULT_CONFIRM_REVISIONS,
) -> Iterator[tuple[Unit, Detection]]:
    """Each unit of the corpus with ``detector``'s verdict on it, series by series in build
    order; the baseline follows the ``recent`` policy (it restarts where the detector flagged a
    change the ``wait`` builds after it did not return from, as a service whose
    ``confirm_revisions`` is ``wait`` restarts it).
    Series the service does not judge are no units, and counts are judged by `CountRate`
    (`measures`). ``progress`` hears after each series."""
    every = list(series_builds(corpus))
    present = {series: dict(builds) for series, _, builds in every}
    for done, (series, label, builds) in enumerate(every, start=1):
        kind = measures(series, label)
        if kind.judged:
            yield from _walk_series(detector, series, label, builds, kind, present, window, wait)
        if progress is not None:
            progress(done, len(every))


def _walk_series(
    detector: Detector,
    series: str,
    label: SeriesLabel,
    builds: list[tuple[int, list[np.ndarray]]],
    kind: Measures,
    present: dict[str, dict[int, list[np.ndarray]]],
    window: int,
    wait: int,
) -> Iterator[tuple[Unit, Detection]]:
    judge = CountRate() if kind.count else detector
    values = [values_for(judge, executions) for _, executions in builds]
    totals: list[np.ndarray | None] = []
    if kind.count:
        of = present.get(total_of(series, label, present) or "", {})
        totals = [values_for(judge, of[b]) if b in of else None for b, _ in builds]
    changes = snapped(label.change_builds, [build for build, _ in builds])
    runs = [executions for _, executions in builds]
    flags: set[int] = set()
    for k in range(1, len(builds)):
        first = max(0, k - lookback(window))  # all a baseline can reach

        def level_before(flag: int, first: int = first) -> list[int]:
            """The positions of the flagged build's own baseline, as `Baselines._take` reads it
            with ``before`` and ``past_undecided``."""
            return take_recent(
                ((p, values[p], p in flags) for p in range(flag - 1, first - 1, -1)),
                judge.baseline_values,
                window,
                wait,
                count=kind.count,
                past_undecided=True,
            )

        depth = recent_depth(
            values[first:k][::-1],
            judge.baseline_values,
            window,
            {k - 1 - j for j in flags}.__contains__,  # positions newest first
            wait,
            count=kind.count,
        )
        baseline, candidate = np.concatenate(values[k - depth : k]), values[k]
        build = builds[k][0]
        flag = k - depth  # where a baseline restarted at a flag begins
        if kind.count:
            found = rate_verdict(values, totals, k, depth)
        elif detector.ndim == 2:
            found = judge_series(detector, kind.counter, baseline[:, None], candidate[:, None])
        else:
            # as the worker judges: the detector, then the counter's absolute floor (a series
            # id ending in a known counter name, e.g. "leak/rss_bytes", gets that floor)
            found = judge_series(detector, kind.counter, baseline, candidate)
            if not found.decided and flag in flags and (older := level_before(flag)):
                # restarted at a flag and too short: as `Baselines.after_flag` (no pairs
                # here, so no confirmed short level before it: `LevelBefore` of one level)
                earlier = np.concatenate([values[p] for p in older])
                found, against = after_flag(
                    found,
                    detector,
                    kind.counter,
                    baseline,
                    LevelBefore(earlier),
                    candidate,
                    str(builds[flag][0]),
                    held=depth > wait,
                )
                baseline = earlier if against == BEFORE else baseline
        unit = Unit(
            series, build, baseline, candidate, build in changes, kind.worse, kind.count, runs, k
        )
        if found.flagged:  # a baseline may restart at any flag, a better or a worse one
            flags.add(k)
        yield unit, found


def alarm(unit: Unit, flagged: bool, direction: str) -> bool:
    """Whether a flag is an alarm: towards the worse where the series says which way that is
    (a flagged improvement opens no regression in the service)."""
    return flagged and unit.worse in ("", direction)


def run_detector(
    detector: Detector, corpus: Corpus, confirm: int = 0, progress: Progress | None = None
) -> list[Outcome]:
    """Each unit's outcome; with ``confirm`` > 0 a flagged unit counts as flagged only when the
    ``confirm`` builds after it hold the new level (`redline.detect.confirmation`, as the
    service confirms by history; a change too near the end of its series stays suspected and
    counts as not flagged)."""
    sizes = change_sizes(corpus)
    # the baselines as a service confirming over ``confirm`` revisions has them (by default, 2)
    judged = list(
        walk(detector, corpus, progress=progress, wait=confirm or DEFAULT_CONFIRM_REVISIONS)
    )
    outcomes = []
    for index, (unit, found) in enumerate(judged):
        flagged, confirmation = alarm(unit, found.flagged, found.direction), ""
        if flagged and confirm > 0:
            after = [
                later.candidate
                for later, _ in judged[index + 1 : index + 1 + confirm]
                if later.series == unit.series
            ]
            confirmation = hold(
                unit.baseline,
                unit.candidate,
                after,
                confirm,
                count=unit.count,
                past=unit.past(LOOKBACK),
            ).state
            flagged = confirmation == HELD
        outcomes.append(
            Outcome(
                unit.positive,
                found.score,
                flagged,
                found.decided,
                sizes.get((unit.series, unit.build), math.nan) if unit.positive else math.nan,
                unit.series,
                unit.build,
                found.verdict,
                confirmation,
            )
        )
    return outcomes


def units_of(corpus: Corpus, progress: Progress | None = None) -> list[Unit]:
    """The corpus's units, with the baselines the default method would use (for E-divisive,
    which judges whole histories but is scored on the same builds)."""
    return [unit for unit, _ in walk(EVALUATED[DEFAULT_METHOD](), corpus, progress=progress)]


def run_change_points(
    corpus: Corpus, units: Sequence[Unit], detector: EDivisive | None = None
) -> list[Outcome]:
    """E-divisive over each series' history of per-build medians, judged on the same units.

    A build scores 1 - p when a significant change point starts at it (0 otherwise) and is
    flagged when that change also passes the effect-size floor. Unlike the other methods this
    looks at the whole history, later builds included: it is a retrospective analysis.
    """
    detector = detector or EDivisive()
    found: dict[tuple[str, int], tuple[float, bool, str]] = {}
    undecided: set[str] = set()
    for series, frame in corpus.measurements.groupby("series", sort=True):
        medians = frame.groupby("build", sort=True)["value"].median()
        result = detector.detect(medians.to_numpy())
        if not result.change_points and result.verdict == "not enough data":
            undecided.add(str(series))
        for point in result.change_points:
            found[(str(series), int(medians.index[point.index]))] = (
                1 - point.p_value,
                point.reported,
                direction_of(point.effect),
            )
    sizes = change_sizes(corpus)
    outcomes = []
    for unit in units:
        score, reported, direction = found.get((unit.series, unit.build), (0.0, False, ""))
        flagged = alarm(unit, reported, direction)
        decided = unit.series not in undecided
        outcomes.append(
            Outcome(
                unit.positive,
                score,
                flagged,
                decided,
                sizes.get((unit.series, unit.build), math.nan) if unit.positive else math.nan,
                unit.series,
                unit.build,
                ("change" if flagged else "no change") if decided else "not enough data",
            )
        )
    return outcomes


#: Called with each method's name, scores and units as soon as the method is done.
Finished = Callable[[str, MethodScores, list[Outcome]], None]


def evaluate_corpus(
    corpus: Corpus,
    methods: Sequence[str] | None = None,
    confirm: int = 0,
    progress: Callable[[str, int, int], None] | None = None,
    finished: Finished | None = None,
) -> dict[str, MethodScores]:
    """Scores of each named method (default: all) on the corpus's units; ``confirm``: the
    later builds a flagged change must hold over (`run_detector`; E-divisive sees the whole
    history and is not confirmed). ``progress`` hears (method, series done, series in all);
    ``finished`` gets each method's figures and units as soon as it is done."""
    names = list(methods) if methods else [*EVALUATED, CHANGE_POINT_METHOD]
    results = {}
    for name in names:

        def step(done: int, total: int, name: str = name) -> None:
            if progress is not None:
                progress(name, done, total)

        if name == CHANGE_POINT_METHOD:
            outcomes = run_change_points(corpus, units_of(corpus, step))
        else:
            outcomes = run_detector(EVALUATED[name](), corpus, confirm, step)
        results[name] = summarize(outcomes)
        if finished is not None:
            finished(name, results[name], outcomes)
    return results


def change_point_f1(
    corpus: Corpus, outcomes: Mapping[str, Sequence[Outcome]], margin: int = MARGIN
) -> dict[str, float]:
    """TCPDBench's F1 (`redline.detect.changepoint_f1`), the mean over the corpus's series, of
    each method's flagged builds, of a detector that never alarms (``zero``) and of binary
    segmentation over the build medians (``binseg``)."""
    positions: dict[str, dict[int, int]] = {}
    truth: dict[str, list[int]] = {}
    levels: dict[str, list[float]] = {}
    for series, label, builds in series_builds(corpus):
        if not measures(series, label).judged:
            continue  # no units: nothing to score
        positions[series] = {build: i for i, (build, _) in enumerate(builds)}
        changes = snapped(label.change_builds, list(positions[series]))
        truth[series] = sorted(positions[series][b] for b in changes)
        levels[series] = [float(np.median(np.concatenate(runs))) for _, runs in builds]
    predicted: dict[str, dict[str, list[int]]] = {}
    for name, found in outcomes.items():
        flagged: dict[str, list[int]] = {series: [] for series in positions}
        for o in found:
            if o.flagged:
                flagged[o.series].append(positions[o.series][o.build])
        predicted[name] = flagged
    predicted["zero"] = {series: [] for series in positions}
    predicted["binseg"] = {s: binary_segmentation(levels[s]) for s in positions}
    return {
        name: float(
            np.mean([f_measure({"labels": truth[s]}, points[s], margin)[0] for s in positions])
        )
        for name, points in predicted.items()
    }
