"""Offline comparison of recordings, for CI without a server (the paper's Jenkins flow).

Baseline and candidate are each one or more recordings; the samples of every series are pooled
per side (the paper: "the individual measurements ... of potentially multiple executions form an
observation") and judged exactly as the service's KS judges them: `redline.detect.verdict`'s
`judge_series` with `KolmogorovSmirnov` (the KS test, then the counter's absolute floor), host-wide
series left out. Results are grouped into one verdict per test case × phase × parameter set.
Reading the files is the only I/O here.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from redline.detect.methods import KolmogorovSmirnov
from redline.detect.result import Detection
from redline.detect.verdict import judge_series
from redline.recording import (
    HOST_PROCESS,
    Recording,
    RecordingError,
    SeriesKey,
    params_name,
    read_recording,
)

Timeline = dict[SeriesKey, list[tuple[int, float]]]
Segment = tuple[str, str, str]  # case, phase, canonical parameters


class CompareError(ValueError):
    """Input that cannot be compared; the message names the file or what is missing."""


@dataclass(frozen=True)
class RecordedSeries:
    """One recording's judged series with their sample times, and how plots should name it."""

    path: Path
    label: str  # file name, with the revision title when the recording has one
    timeline: Timeline


@dataclass(frozen=True)
class SeriesVerdict:
    key: SeriesKey
    result: Detection  # score: KS's D; verdict "not enough data" names why (too few, constant)
    baseline_mean: float
    candidate_mean: float
    baseline_n: int
    candidate_n: int


@dataclass(frozen=True)
class SegmentVerdict:
    """One test case × phase × parameter set; ``note`` says why it could not be compared."""

    case: str
    phase: str
    params: str
    series: tuple[SeriesVerdict, ...] = ()
    note: str = ""

    @property
    def name(self) -> str:
        return f"{self.case}/{self.phase}[{params_name_of(self.params)}]"

    @property
    def changed(self) -> list[SeriesVerdict]:
        return [verdict for verdict in self.series if verdict.result.flagged]


@dataclass(frozen=True)
class Comparison:
    baseline: tuple[RecordedSeries, ...]
    candidate: tuple[RecordedSeries, ...]
    segments: tuple[SegmentVerdict, ...] = field(default=())

    @property
    def changed(self) -> list[SeriesVerdict]:
        return [verdict for segment in self.segments for verdict in segment.changed]


def params_name_of(canonical: str) -> str:
    """The printable name of a canonical parameter set, e.g. ``legs=4,rate=10``."""
    return params_name(json.loads(canonical))


def _label(recording: Recording) -> str:
    title = recording.run.get("revision_title", "")
    return f"{recording.path.name} ({title})" if title else recording.path.name


def load_side(paths: Sequence[str | Path], side: str) -> tuple[RecordedSeries, ...]:
    """Read a side's recordings strictly; CompareError names the first file that is unusable."""
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
        timeline = {
            key: points
            for key, points in recording.series_timeline().items()
            if key.process != HOST_PROCESS
        }  # the machine's context, not judged
        loaded.append(RecordedSeries(path=path, label=_label(recording), timeline=timeline))
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


def _verdict(key: SeriesKey, base: np.ndarray, cand: np.ndarray) -> SeriesVerdict:
    return SeriesVerdict(
        key=key,
        result=judge_series(KolmogorovSmirnov(), key.counter, base, cand),
        baseline_mean=float(np.mean(base)),
        candidate_mean=float(np.mean(cand)),
        baseline_n=int(base.size),
        candidate_n=int(cand.size),
    )


def compare_sides(
    baseline: tuple[RecordedSeries, ...], candidate: tuple[RecordedSeries, ...]
) -> Comparison:
    """Judge every series both sides hold; CompareError when they hold none in common."""
    base, cand = pooled(baseline), pooled(candidate)
    common = sorted(set(base) & set(cand))
    if not common:
        raise CompareError(
            f"the baseline and the candidate have no series in common (baseline: "
            f"{len(base)} series, candidate: {len(cand)}; compare recordings of "
            f"the same test cases, phases and parameter sets)"
        )
    by_segment: dict[Segment, list[SeriesVerdict]] = {}
    for key in common:
        by_segment.setdefault(_segment(key), []).append(_verdict(key, base[key], cand[key]))
    segments = [SegmentVerdict(*ident, series=tuple(found)) for ident, found in by_segment.items()]
    for side, only in (("baseline", base), ("candidate", cand)):
        for ident in sorted({_segment(key) for key in only} - set(by_segment)):
            segments.append(SegmentVerdict(*ident, note=f"recorded only in the {side}"))
    segments.sort(key=lambda s: (s.case, s.phase, s.params))
    return Comparison(baseline=baseline, candidate=candidate, segments=tuple(segments))


def compare_files(baseline: Sequence[str | Path], candidate: Sequence[str | Path]) -> Comparison:
    """Read both sides and compare them (raises CompareError on bad input)."""
    return compare_sides(load_side(baseline, "baseline"), load_side(candidate, "candidate"))
