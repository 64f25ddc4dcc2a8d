"""Why a change was flagged: what a detection compared, laid out for the "why flagged" page.

A detection stores its verdict, score, effect, newest baseline revision and how many revisions
its baseline pooled. This gathers what it judged from the stored summaries: each execution's
value (the median of its samples, what `execution_shift` judges) and its distribution (the
32-quantile sketch, from which a sample-level method's two sides are drawn as ECDFs), for the
candidate revision and the baseline's revisions (the newest ``baseline_revisions`` revisions up
to the newest baseline revision that measured the series); the method's thresholds as they judged
it (kept with the verdict; for one judged before they were kept, as the component is configured
now, and the page says so), the counter's absolute floor, and the confirmation pairs' values when
the change was re-run. Only the revisions' own executions count, as for the detection itself.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from typing import Any

from redline.detect.execution_shift import STEP_FOUND, STEP_MARGIN
from redline.detect.floors import absolute_floor
from redline.detect.registry import DETECTORS
from redline.server.models import (
    Detection,
    Execution,
    Job,
    JobState,
    Revision,
    Series,
    Summary,
    revision_place,
)
from redline.server.schemas.regressions import DetectionOut
from redline.server.services.detection_config import component_config, judged_params
from redline.server.services.jobs import current_pairs
from redline.server.services.regressions import detection_by_id
from sqlalchemy import select
from sqlalchemy.orm import Session


@dataclass(frozen=True)
class ExecutionValue:
    revision: str
    execution: int  # the execution's id
    median: float
    mean: float
    n: int
    sketch: list[float]
    disturbed: bool = False  # measured while the host was busy: left out of the verdict


@dataclass
class WhyFlagged:
    component: str
    detection: DetectionOut
    candidate: list[ExecutionValue]
    baseline: list[ExecutionValue]
    baseline_titles: list[str]  # oldest first
    thresholds: dict[str, Any]
    #: whether ``thresholds`` are those the verdict was judged by (kept with it) or, for a
    #: verdict judged before they were kept, the component's configuration as it is now
    thresholds_judged: bool
    floor: float
    rule: str  # what the method's score is and how it decides, in its own words
    #: why ``threshold`` is not the configured one ("" when it is)
    bar: str = ""
    #: (pair, baseline's median, candidate's median, whether the host was busy in either run:
    #: then it was left out, as confirmation leaves it out)
    pairs: list[tuple[int, float | None, float | None, bool]] = field(default_factory=list)


def execution_values(
    session: Session, series_id: int, revision_ids: list[int]
) -> list[ExecutionValue]:
    """The series' value in each of the revisions' own executions (not confirmation runs')."""
    rows = session.execute(
        select(Revision.title, Execution.id, Summary.p50, Summary.mean, Summary.n, Summary.sketch)
        .add_columns(Summary.disturbed)
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Job, Job.id == Execution.job_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(
            Summary.series_id == series_id,
            Execution.revision_id.in_(revision_ids),
            Job.pair == 0,
        )
        .order_by(Revision.order_key, Revision.id, Execution.id)
    )
    return [
        ExecutionValue(title, ident, p50, mean, n, list(sketch or []), bool(disturbed))
        for title, ident, p50, mean, n, sketch, disturbed in rows
    ]


def baseline_revisions(
    session: Session, series_id: int, newest_id: int | None, count: int
) -> list[Revision]:
    """The ``count`` newest revisions up to ``newest_id`` with the series measured undisturbed:
    the detection's baseline as it pooled it (a ``recent`` or ``window`` baseline; one for
    ``previous``), which passed over the revisions the host was busy in throughout."""
    if newest_id is None or count <= 0:
        return []
    newest = session.get(Revision, newest_id)
    if newest is None:
        return []
    measured = (
        select(Execution.revision_id)
        .join(Summary, Summary.execution_id == Execution.id)
        .join(Job, Job.id == Execution.job_id)
        .where(Summary.series_id == series_id, Job.pair == 0, Summary.disturbed.is_(False))
    )
    rows = session.scalars(
        select(Revision)
        .where(
            Revision.component_id == newest.component_id,
            revision_place() <= newest.place,
            Revision.id.in_(measured),
        )
        .order_by(Revision.order_key.desc(), Revision.id.desc())
        .limit(count)
    )
    return list(rows)[::-1]


def _pairs(
    session: Session, detection: Detection
) -> list[tuple[int, float | None, float | None, bool]]:
    """(pair, baseline's median, candidate's median, left out) of each of the newest
    confirmation pairs that ran (`current_pairs`: those queued against another baseline measured
    another comparison); left out: the host was busy in either run of the series (a trial's
    page listed four pairs beside "confirmed by 2 of 3 pairs", the busy one unmarked)."""
    jobs = session.scalars(select(Job).where(Job.confirms_revision_id == detection.revision_id))
    _, newest = current_pairs(list(jobs), detection.revision_id)
    rows = session.execute(
        select(Job.pair, Job.revision_id, Summary.p50, Summary.disturbed)
        .join(Execution, Execution.job_id == Job.id)
        .join(Summary, Summary.execution_id == Execution.id)
        .where(
            Job.id.in_([job.id for job in newest]),
            Job.state == JobState.done,
            Summary.series_id == detection.series_id,
        )
    )
    found: dict[int, list[float | None]] = {}
    busy: set[int] = set()
    for pair, revision_id, value, disturbed in rows:
        side = 1 if revision_id == detection.revision_id else 0
        found.setdefault(pair, [None, None])[side] = value
        if disturbed:
            busy.add(pair)
    return [(pair, sides[0], sides[1], pair in busy) for pair, sides in sorted(found.items())]


def why_flagged(session: Session, detection_id: int) -> WhyFlagged:
    detection, out = detection_by_id(session, detection_id)
    series = session.get_one(Series, detection.series_id)
    revision = session.get_one(Revision, detection.revision_id)
    baseline = baseline_revisions(
        session, series.id, detection.baseline_revision_id, detection.baseline_revisions
    )
    thresholds = judged_params(session, detection.config_id, detection.method)
    judged = thresholds is not None
    if thresholds is None:
        thresholds = _configured_now(session, revision.component_id, detection.method)
    thresholds.pop("confirmed_threshold", None)  # ``threshold`` is the bar it judged at
    step = thresholds.pop("step_threshold", None)
    bar = ""
    if step is not None and detection.reason.startswith(STEP_FOUND):  # a step's own bar
        thresholds["threshold"] = round(STEP_MARGIN * step, 6)
        bar = f"a step found later: judged at {step:g} × {STEP_MARGIN:g}, and no pair judges it"
    return WhyFlagged(
        component=revision.component.name,
        detection=out,
        candidate=execution_values(session, series.id, [revision.id]),
        baseline=execution_values(session, series.id, [r.id for r in baseline]),
        baseline_titles=[r.title for r in baseline],
        thresholds=thresholds,
        thresholds_judged=judged,
        bar=bar,
        floor=absolute_floor(series.counter),
        rule=_rule(detection.method),
        pairs=_pairs(session, detection),
    )


def _configured_now(session: Session, component_id: int, method: str) -> dict[str, Any]:
    """``method``'s parameters as the component's configuration sets them now, as it judges:
    where re-runs confirm, at that bar."""
    config = component_config(session, component_id)
    if method in DETECTORS:
        return config.detector(method).params_as_judged()
    return dict(config.thresholds.get(method, {}))


def _rule(method: str) -> str:
    """The first paragraph of the method's own description (each method scores differently:
    KS's score is D, and a change needs its p below alpha; a page said "a change needs 1 or
    more" for every method, beside a KS change of D = 0.95)."""
    described = inspect.getdoc(DETECTORS[method]) if method in DETECTORS else None
    return " ".join((described or "").split("\n\n")[0].split()).replace("``", "").replace("`", "")
