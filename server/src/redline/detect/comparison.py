"""What `redline compare` answers: each series' verdict, grouped by test case × phase × parameter
set (`SegmentVerdict`, with its state: failed, undecided, skipped or passed), and the whole
`Comparison`; `redline.detect.compare` reads the recordings and judges them."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from redline.detect.counters import worse
from redline.detect.result import Detection
from redline.detect.verdict import TOO_FEW
from redline.recording import SeriesKey, params_name

Timeline = dict[SeriesKey, list[tuple[int, float]]]
Segment = tuple[str, str, str]  # case, phase, canonical parameters

#: the reason of a series only one side holds: a renamed action path leaves its old series only
#: in the baseline and its new one only in the candidate, a report missing from every candidate
#: run leaves its series only in the baseline. One only in the baseline makes its segment
#: undecided (`SegmentVerdict.state`); one only in the candidate is new, listed
ONLY_IN = "only in the {side}: {why}"
WHY_DRIVER = "the action path changed or the report is missing"
WHY_PROCESS = "the process, test case, phase or parameter set changed, or it was not measured"


#: A segment the host was busy in, judged on what the component holds alone (``{why}``: which
#: recording said so): a change there fails; without one it is undecided, its CPU and rates
#: unjudged
BUSY_PART = (
    "judged in part: the host was busy ({why}); what the component holds and other load does "
    "not move (memory, processes, files) was judged, its CPU, rates and threads were not"
)
#: A segment the host was busy in where the two sides hold nothing in common to judge
NOT_JUDGED_BUSY = "not judged: the host was busy ({why})"


class CompareError(ValueError):
    """Input that cannot be compared; the message names the file or what is missing."""


@dataclass(frozen=True)
class RecordedSeries:
    """One recording's judged series with their sample times, and how plots should name it."""

    path: Path
    label: str  # file name, with the revision title when the recording has one
    timeline: Timeline
    #: (case, phase, params) → why: the segments the host was busy in (a warning, not a verdict)
    disturbed: dict[Segment, str] = field(default_factory=dict)


@dataclass(frozen=True)
class SeriesVerdict:
    key: SeriesKey
    result: Detection  # score: KS's D; verdict "not enough data" names why (too few, constant)
    baseline_mean: float
    candidate_mean: float
    baseline_n: int
    candidate_n: int
    #: "baseline" or "candidate" for a series only that side holds (not judged), else ""
    only_in: str = ""


@dataclass(frozen=True)
class SegmentVerdict:
    """One test case × phase × parameter set; ``note`` says why it could not be compared (the
    host was busy)."""

    case: str
    phase: str
    params: str
    series: tuple[SeriesVerdict, ...] = ()
    note: str = ""

    @property
    def in_part(self) -> bool:
        """Judged only in what the component holds: the host was busy (`BUSY_PART`)."""
        return self.note.startswith(BUSY_PART.split(":", 1)[0])

    @property
    def name(self) -> str:
        return f"{self.case}/{self.phase}[{params_name_of(self.params)}]"

    @property
    def changed(self) -> list[SeriesVerdict]:
        """The changes for the worse (what fails a comparison)."""
        return [verdict for verdict in self.series if _for_the_worse(verdict)]

    @property
    def improved(self) -> list[SeriesVerdict]:
        """The changes for the better: reported, never a failure."""
        return [v for v in self.series if v.result.flagged and not _for_the_worse(v)]

    @property
    def lost(self) -> list[SeriesVerdict]:
        """The series only the baseline holds: measurements the comparison lost, not judged."""
        return [v for v in self.series if v.only_in == "baseline"]

    @property
    def too_few(self) -> list[SeriesVerdict]:
        """The series whose sides did not overlap, too few values a side for KS to call it."""
        return [v for v in self.series if (v.result.reason or "").startswith(TOO_FEW)]

    @property
    def new(self) -> list[SeriesVerdict]:
        """The series only the candidate holds: nothing to compare them with yet."""
        return [v for v in self.series if v.only_in == "candidate"]

    @property
    def state(self) -> str:
        """``failed`` (a change for the worse, also one of what the component holds in a
        segment the host was busy in), ``undecided`` (no such change, but the host
        was busy, a series only the baseline holds, or one too few values a side kept KS from
        calling: what was not measured, or not enough, cannot pass),
        ``skipped`` (a segment only the candidate recorded) or ``passed``."""
        if self.changed:
            return "failed"
        if self.note:
            return "undecided"
        if self.lost or self.too_few:
            return "undecided"
        if all(v.only_in for v in self.series):
            return "skipped"
        return "passed"


@dataclass(frozen=True)
class Comparison:
    baseline: tuple[RecordedSeries, ...]
    candidate: tuple[RecordedSeries, ...]
    segments: tuple[SegmentVerdict, ...] = field(default=())

    @property
    def changed(self) -> list[SeriesVerdict]:
        return [verdict for segment in self.segments for verdict in segment.changed]

    @property
    def improved(self) -> list[SeriesVerdict]:
        return [verdict for segment in self.segments for verdict in segment.improved]

    @property
    def lost(self) -> list[SeriesVerdict]:
        return [verdict for segment in self.segments for verdict in segment.lost]

    @property
    def too_few(self) -> list[SeriesVerdict]:
        return [verdict for segment in self.segments for verdict in segment.too_few]

    @property
    def busy(self) -> list[SegmentVerdict]:
        """The segments the host was busy in that were not judged whole: not at all, or only
        in what the component holds (`SegmentVerdict.in_part`)."""
        return [segment for segment in self.segments if segment.note]


def _for_the_worse(verdict: SeriesVerdict) -> bool:
    key = verdict.key
    return verdict.result.flagged and verdict.result.direction == worse(key.process, key.counter)


def params_name_of(canonical: str) -> str:
    """The printable name of a canonical parameter set, e.g. ``legs=4,rate=10``."""
    return params_name(json.loads(canonical))
