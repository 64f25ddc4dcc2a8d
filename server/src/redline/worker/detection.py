"""Detection over stored results: each series of a revision against its baseline, every method.

The component's configuration (`redline.detect.config.DetectionConfig`, table ``detection_config``;
defaults when absent) names the methods and the baseline: ``recent`` (the newest earlier revisions
with samples of the series, pooled until the method has enough values, restarting at the method's
newest flagged change; `redline.detect.baseline`), the previous revision (by sort key), a window of
the previous n such revisions pooled, or a pinned revision. Execution-level methods get one value
per execution (its median), the others all samples. Every method's verdict on every series is stored
as a `Detection` — "not enough data" with the reason included (no baseline, too few samples,
constant, NaN/inf) — and KS's decided comparisons also as `Change` rows, which the trend charts and
``/api/v1/components/{name}/changes`` show. Flagged detections are then grouped into regressions
(`redline.worker.grouping`). Samples come from the Parquet side tables written at ingestion. Host-
wide series are context, never judged.
"""

from __future__ import annotations

import logging
from collections import defaultdict, deque
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from datetime import datetime
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from redline.detect.baseline import take_recent
from redline.detect.config import ConfigError, DetectionConfig
from redline.detect.executions import values_for
from redline.detect.methods import Detector
from redline.detect.result import NOT_ENOUGH_DATA
from redline.detect.result import Detection as Verdict
from redline.detect.verdict import judge_series
from redline.recording.format import HOST_PROCESS
from redline.server.db import bulk_insert, session_scope
from redline.server.models import (
    Change,
    Execution,
    Job,
    JobState,
    Revision,
    Series,
    Summary,
    utcnow,
)
from redline.server.models_regressions import Detection, DetectionConfigRow
from redline.server.storage import samples_path
from redline.worker.grouping import group_revision
from sqlalchemy import Select, delete, func, select, text, tuple_
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)
METHOD_KS = "ks"
#: the first key of the transaction-scoped advisory lock one revision's detection holds
DETECT_LOCK = 0x5244  # "RD"


def ingested_executions() -> Select[tuple[int]]:
    """Executions whose ingestion finished (their job is done), whatever series they hold: a
    recording whose every sample was NaN has no summary rows but must still be judged."""
    return (
        select(Execution.id).join(Job, Job.id == Execution.job_id).where(Job.state == JobState.done)
    )


#: Per series id, one array of samples per execution (in execution order).
Samples = dict[int, list[np.ndarray]]


def _ingested(session: Session, revision_id: int) -> list[tuple[int, str]]:
    """(id, recording path) of the revision's ingested executions, in execution order."""
    return [
        (execution_id, path)
        for execution_id, path in session.execute(
            select(Execution.id, Execution.recording_path)
            .where(Execution.revision_id == revision_id, Execution.id.in_(ingested_executions()))
            .order_by(Execution.id)
        )
    ]


def read_samples(session: Session, revision_id: int) -> tuple[Samples, int, tuple[int, ...]]:
    """Every ingested sample of the revision, per series id and execution; with how many of
    its ingested executions' side tables were read, and the ids of those executions.

    A side table that is gone (pruned) is left out with a warning: its series then lack data.
    """
    executions = _ingested(session, revision_id)
    samples: Samples = defaultdict(list)
    read = 0
    for _, path in executions:
        try:
            table = pq.read_table(samples_path(path), columns=["series_id", "value"])
        except OSError as exc:
            log.warning("revision %s: samples of %s unreadable: %s", revision_id, path, exc)
            continue
        read += 1
        series = table.column("series_id").to_numpy()
        values = table.column("value").to_numpy()
        order = np.argsort(series, kind="stable")
        ids, starts = np.unique(series[order], return_index=True)
        for series_id, chunk in zip(ids.tolist(), np.split(values[order], starts[1:]), strict=True):
            samples[series_id].append(chunk)
    return dict(samples), read, tuple(execution_id for execution_id, _ in executions)


def revision_samples(session: Session, revision_id: int) -> Samples:
    """Every ingested and still readable sample of the revision, per series and execution."""
    return read_samples(session, revision_id)[0]


class SampleCache:
    """Revisions' samples, read once, and the values each detector level makes of them, made
    once: a re-analysis walks the history in order, so the newest ``size`` revisions (the
    baseline window and the candidate) are all it needs; the oldest is dropped first, which
    bounds memory whatever the history's length."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.entries: dict[int, Samples] = {}
        self.reduced: dict[int, dict[tuple[int, str], np.ndarray]] = {}

    def get(self, session: Session, revision_id: int) -> Samples:
        if revision_id not in self.entries:
            self.put(revision_id, revision_samples(session, revision_id))
        return self.entries[revision_id]

    def put(self, revision_id: int, samples: Samples) -> None:
        self.entries.pop(revision_id, None)
        self.reduced.pop(revision_id, None)
        while len(self.entries) >= self.size:
            oldest = next(iter(self.entries))
            del self.entries[oldest]
            self.reduced.pop(oldest, None)
        self.entries[revision_id] = samples

    def values(
        self, session: Session, revision_id: int, series_id: int, detector: Detector
    ) -> np.ndarray | None:
        """The revision's values of the series as ``detector`` judges them; None if absent."""
        samples = self.get(session, revision_id)
        if series_id not in samples:
            return None
        memo = self.reduced.setdefault(revision_id, {})
        key = (series_id, detector.level)
        if key not in memo:
            memo[key] = values_for(detector, samples[series_id])
        return memo[key]


def ingested_fingerprint(session: Session, component_id: int) -> tuple[int, int]:
    """How many executions of the component are ingested, and the newest one's id: it changes
    whenever an execution is ingested (or removed), so a re-analysis can tell its memory of the
    history went stale."""
    count, newest = session.execute(
        select(func.count(Execution.id), func.coalesce(func.max(Execution.id), 0))
        .join(Revision, Revision.id == Execution.revision_id)
        .where(Revision.component_id == component_id, Execution.id.in_(ingested_executions()))
    ).one()
    return int(count), int(newest)


@dataclass
class Walk:
    """What a re-analysis carries from one revision to the next, so that a revision's baselines
    need nothing read back: earlier revisions' samples, every flagged (series, method,
    revision) so far, and the newest revisions with summaries, each with the series it has
    summaries of (a series with at least one finite sample), newest last.

    Valid only while the history stays as it was when the walk began (``fingerprint``) and the
    configuration's window is the walk's: otherwise ``usable`` turns False for good, and the
    revisions left are judged from the database as `detect_revision` judges them.
    """

    cache: SampleCache
    window: int
    fingerprint: tuple[int, int]
    flagged: set[tuple[int, str, int]] = field(default_factory=set)
    recent: deque[tuple[int, frozenset[int]]] = field(default_factory=deque)
    usable: bool = True
    #: called once when the walk turns unusable, before anything is read from the database
    #: (a re-analysis waits there until every revision judged so far is stored)
    on_disable: Callable[[], None] | None = None

    @classmethod
    def over(cls, window: int, fingerprint: tuple[int, int]) -> Walk:
        return cls(SampleCache(window + 1), window, fingerprint, recent=deque(maxlen=window))

    def check(self, session: Session, component_id: int) -> None:
        """Stop using the memory if executions were ingested since the walk began."""
        if self.usable and ingested_fingerprint(session, component_id) != self.fingerprint:
            self.disable(f"component {component_id}: executions ingested during the re-analysis")

    def disable(self, why: str) -> None:
        log.info("%s; the rest of the re-analysis reads its baselines from the database", why)
        self.usable = False
        if self.on_disable is not None:
            self.on_disable()

    def newest_first(self) -> list[tuple[int, frozenset[int]]]:
        return list(reversed(self.recent))

    def judged(
        self,
        session: Session,
        revision_id: int,
        samples: Samples,
        rows: list[dict[str, Any]],
        complete: bool,
    ) -> None:
        """``complete``: every ingested execution's samples were read; else the revision's
        series are those its summaries name, as the database sees them."""
        self.flagged.update(
            (row["series_id"], row["method"], revision_id) for row in rows if row["flagged"]
        )
        if complete:
            self._add(
                revision_id,
                frozenset(
                    series_id
                    for series_id, runs in samples.items()
                    if any(np.isfinite(run).any() for run in runs)
                ),
            )
        else:
            self._add(revision_id, _summarized_series(session, revision_id))

    def kept(self, session: Session, revision_id: int) -> None:
        """A revision whose samples are gone: its stored verdicts and summaries still count."""
        self.flagged |= flagged_verdicts(session, {revision_id})
        self._add(revision_id, _summarized_series(session, revision_id))

    def _add(self, revision_id: int, series: frozenset[int]) -> None:
        if series:  # a revision without summaries is no earlier revision "with samples"
            self.recent.append((revision_id, series))


def _summarized_series(session: Session, revision_id: int) -> frozenset[int]:
    return frozenset(
        session.scalars(
            select(Summary.series_id)
            .distinct()
            .join(Execution, Execution.id == Summary.execution_id)
            .where(Execution.revision_id == revision_id)
        )
    )


def _before(revision: Revision):  # noqa: ANN202 - an SQL expression
    return tuple_(Revision.order_key, Revision.id) < (revision.order_key, revision.id)


def successor_with_data(session: Session, revision_id: int) -> int | None:
    """The next revision (by sort key) of the same component that has ingested results."""
    revision = session.get_one(Revision, revision_id)
    return session.scalar(
        select(Revision.id)
        .join(Execution, Execution.revision_id == Revision.id)
        .where(
            Revision.component_id == revision.component_id,
            tuple_(Revision.order_key, Revision.id) > (revision.order_key, revision.id),
            Execution.id.in_(ingested_executions()),
        )
        .order_by(Revision.order_key, Revision.id)
        .limit(1)
    )


def component_config(session: Session, component_id: int) -> DetectionConfig:
    """The stored configuration, or the defaults (also when the stored one no longer parses)."""
    row = session.get(DetectionConfigRow, component_id)
    try:
        return DetectionConfig.parse(row.config if row else None)
    except ConfigError as exc:
        log.error(
            "component %s: stored detection configuration unusable (%s); defaults used",
            component_id,
            exc,
        )
        return DetectionConfig()


def _judged_counters(session: Session, series_ids: list[int]) -> dict[int, str]:
    """Series id → counter, for the component's own processes (host-wide series are context)."""
    rows = session.execute(
        select(Series.id, Series.counter).where(
            Series.id.in_(series_ids), Series.process != HOST_PROCESS
        )
    )
    return {series_id: counter for series_id, counter in rows}


def _newest_with_summaries(session: Session, revision: Revision, depth: int) -> list[int]:
    has_samples = (
        select(Summary.id)
        .join(Execution, Execution.id == Summary.execution_id)
        .where(Execution.revision_id == Revision.id)
        .exists()
    )
    return list(
        session.scalars(
            select(Revision.id)
            .where(Revision.component_id == revision.component_id, _before(revision), has_samples)
            .order_by(Revision.order_key.desc(), Revision.id.desc())
            .limit(depth)
        )
    )


def _ranked_previous(
    session: Session, revision: Revision, series_ids: list[int], depth: int
) -> dict[int, list[int]]:
    """Per series, the ids of the ``depth`` newest earlier revisions with samples of it, by
    ranking every earlier revision's summaries of those series (the general case)."""
    rank = func.dense_rank().over(
        partition_by=Summary.series_id, order_by=(Revision.order_key.desc(), Revision.id.desc())
    )
    ranked = (
        select(Summary.series_id, Revision.id.label("revision_id"), rank.label("rank"))
        .join(Execution, Execution.id == Summary.execution_id)
        .join(Revision, Revision.id == Execution.revision_id)
        .where(
            Revision.component_id == revision.component_id,
            Summary.series_id.in_(series_ids),
            _before(revision),
        )
        .subquery()
    )
    rows = session.execute(
        select(ranked.c.series_id, ranked.c.revision_id, ranked.c.rank)
        .where(ranked.c.rank <= depth)
        .distinct()
        .order_by(ranked.c.series_id, ranked.c.rank)
    )
    found: dict[int, list[int]] = defaultdict(list)
    for series_id, revision_id, _rank in rows:
        if revision_id not in found[series_id]:
            found[series_id].append(revision_id)
    return found


def _previous_revisions(
    session: Session,
    revision: Revision,
    series_ids: list[int],
    depth: int,
    known: Sequence[tuple[int, frozenset[int]]] | None = None,
) -> dict[int, list[int]]:
    """Per series, the ids of the ``depth`` newest earlier revisions with samples of it.

    The newest ``depth`` earlier revisions with results nearly always hold every series: they
    are looked up first (an index walk, whatever the history's length), or taken from ``known``
    (newest first, each with the series it has summaries of: a re-analysis's `Walk`); only the
    series some of them lack are ranked over the whole history. Ranking every series each time
    made a re-analysis quadratic in the history's length.
    """
    holds: dict[int, set[int]] = defaultdict(set)
    if known is not None:
        newest = [revision_id for revision_id, _ in known[:depth]]
        for revision_id, series in known[:depth]:
            for series_id in series:
                holds[series_id].add(revision_id)
    else:
        newest = _newest_with_summaries(session, revision, depth)
    if newest and known is None:
        rows = session.execute(
            select(Summary.series_id, Execution.revision_id)
            .distinct()
            .join(Execution, Execution.id == Summary.execution_id)
            .where(Execution.revision_id.in_(newest), Summary.series_id.in_(series_ids))
        )
        for series_id, revision_id in rows:
            holds[series_id].add(revision_id)
    found = {series_id: [r for r in newest if r in holds[series_id]] for series_id in series_ids}
    # fewer than `depth` revisions with results: there is nothing older to look through
    lacking = [s for s in series_ids if len(found[s]) < depth] if len(newest) == depth else []
    if lacking:
        found.update(_ranked_previous(session, revision, lacking, depth))
    return {series_id: ids for series_id, ids in found.items() if ids}


@dataclass(frozen=True)
class Baseline:
    values: np.ndarray | None
    newest: int | None = None  # the newest baseline revision
    revisions: int = 0
    missing: str = ""


def flagged_verdicts(
    session: Session, revision_ids: set[int], series_ids: list[int] | None = None
) -> set[tuple[int, str, int]]:
    """(series, method, revision) of the stored flagged verdicts of those revisions (and of
    those series, when given)."""
    if not revision_ids:
        return set()
    query = select(Detection.series_id, Detection.method, Detection.revision_id).where(
        Detection.flagged, Detection.revision_id.in_(revision_ids)
    )
    if series_ids is not None:
        query = query.where(Detection.series_id.in_(series_ids))
    rows = session.execute(query)
    return {(series_id, method, revision_id) for series_id, method, revision_id in rows}


class Baselines:
    """Each series' baseline for each method under the configuration."""

    def __init__(
        self,
        session: Session,
        revision: Revision,
        config: DetectionConfig,
        series_ids: list[int],
        walk: Walk | None = None,
    ) -> None:
        """``walk``: what a re-analysis knows of the earlier revisions; else it is read."""
        self.session, self.config = session, config
        self.cache = walk.cache if walk else SampleCache(config.window + 1)
        self.pinned: int | None = None
        self.flagged: set[tuple[int, str, int]] = walk.flagged if walk else set()
        if config.baseline == "pinned":
            self.pinned = session.scalar(
                select(Revision.id).where(
                    Revision.component_id == revision.component_id,
                    Revision.title == config.pinned,
                    _before(revision),
                )
            )
            self.previous: dict[int, list[int]] = {}
            return
        depth = 1 if config.baseline == "previous" else config.window
        self.previous = _previous_revisions(
            session, revision, series_ids, depth, walk.newest_first() if walk else None
        )
        if config.baseline == "recent" and walk is None:
            earlier = {r for ids in self.previous.values() for r in ids}
            self.flagged = flagged_verdicts(session, earlier, series_ids)

    def values(self, revision_id: int, series_id: int, detector: Detector) -> np.ndarray | None:
        return self.cache.values(self.session, revision_id, series_id, detector)

    def _revisions(self, series_id: int, detector: Detector) -> list[tuple[int, np.ndarray]]:
        """The baseline's revisions, newest first, with the detector's values of the series."""
        if self.config.baseline == "pinned":
            ids = [self.pinned] if self.pinned is not None else []
        else:
            ids = self.previous.get(series_id, [])
        present = (
            (i, values) for i in ids if (values := self.values(i, series_id, detector)) is not None
        )
        if self.config.baseline != "recent":
            return list(present)
        return take_recent(
            (
                ((i, values), len(values), (series_id, detector.name, i) in self.flagged)
                for i, values in present
            ),
            detector.baseline_values,
            self.config.window,
        )

    def of(self, series_id: int, detector: Detector) -> Baseline:
        if self.config.baseline == "pinned" and self.pinned is None:
            return Baseline(
                None,
                missing=f"missing baseline: pinned revision "
                f"{self.config.pinned!r} is not an earlier revision",
            )
        found = self._revisions(series_id, detector)
        if not found:
            known = self.pinned is not None or self.previous.get(series_id)
            return Baseline(
                None,
                missing="missing baseline: the baseline revision's samples "
                "of this series are unreadable or absent"
                if known
                else "missing baseline: no earlier revision has samples of this series",
            )
        return Baseline(np.concatenate([values for _, values in found]), found[0][0], len(found))


def _row(series_id: int, revision_id: int, base: Baseline, verdict: Verdict) -> dict[str, Any]:
    """A `Detection` row, as the values of a bulk insert."""
    effect = verdict.effect if verdict.decided and np.isfinite(verdict.effect) else None
    return dict(
        series_id=series_id,
        revision_id=revision_id,
        baseline_revision_id=base.newest,
        baseline_revisions=base.revisions,
        method=verdict.method,
        verdict=verdict.verdict,
        reason=verdict.reason,
        score=float(verdict.score),
        p_value=None if verdict.p_value is None else float(verdict.p_value),
        effect=None if effect is None else float(effect),
        direction=verdict.direction,
        flagged=bool(verdict.flagged),
        created=utcnow(),
    )


@dataclass(frozen=True)
class KsChange:
    """KS's decided comparison of a series, as the `Change` row the trend charts draw (plain
    data: 100 series a revision made ORM objects a re-analysis's largest Python cost)."""

    series_id: int
    revision_id: int
    baseline_revision_id: int | None
    method: str
    score: float
    p_value: float
    effect: float
    flagged: bool
    created: datetime


def _ks_change(row: dict[str, Any], verdict: Verdict) -> KsChange | None:
    if row["method"] != METHOD_KS or verdict.verdict == NOT_ENOUGH_DATA or verdict.p_value is None:
        return None
    return KsChange(
        series_id=row["series_id"],
        revision_id=row["revision_id"],
        baseline_revision_id=row["baseline_revision_id"],
        method=METHOD_KS,
        score=float(verdict.score),
        p_value=float(verdict.p_value),
        effect=float(verdict.effect),
        flagged=bool(verdict.flagged),
        created=row["created"],
    )


def analyze(
    session: Session,
    revision: Revision,
    config: DetectionConfig,
    candidate: Samples | None = None,
    walk: Walk | None = None,
) -> tuple[list[dict[str, Any]], list[KsChange]]:
    """Every configured method on every judged series of the revision (nothing stored).

    ``candidate``: the revision's samples, when already read; ``walk``: what a re-analysis
    carries from the earlier revisions (`Walk`).
    """
    if candidate is None:
        candidate = revision_samples(session, revision.id)
    counters = _judged_counters(session, list(candidate))
    baselines = Baselines(session, revision, config, sorted(counters), walk)
    baselines.cache.put(revision.id, candidate)
    detectors = config.detectors()
    rows, changes = [], []
    for series_id in sorted(counters):
        for detector in detectors:
            base = baselines.of(series_id, detector)
            values = baselines.values(revision.id, series_id, detector)
            verdict = judge_series(
                detector, counters[series_id], base.values, values, missing=base.missing
            )
            rows.append(_row(series_id, revision.id, base, verdict))
            change = _ks_change(rows[-1], verdict)
            if change is not None:
                changes.append(change)
    return rows, changes


def store(
    session: Session, revision: Revision, rows: list[dict[str, Any]], changes: list[KsChange]
) -> None:
    """Replace the revision's detections and KS changes, then regroup its regressions.

    One statement per table (`bulk_insert`): 500 series x 2 methods would otherwise spend more
    time in the ORM and in round trips than in the detectors.
    """
    session.execute(delete(Detection).where(Detection.revision_id == revision.id))
    session.execute(
        delete(Change).where(Change.revision_id == revision.id, Change.method == METHOD_KS)
    )
    bulk_insert(session, Detection.__table__, rows)
    bulk_insert(session, Change.__table__, [asdict(change) for change in changes])
    group_revision(session, revision)
    revision.analyzed_at = utcnow()


@dataclass(frozen=True)
class Judged:
    """One revision's verdicts and KS changes, computed and not yet stored, and the ingested
    executions they were computed from."""

    revision_id: int
    rows: list[dict[str, Any]]
    changes: list[KsChange]
    executions: tuple[int, ...]


def judge_revision(session: Session, revision_id: int, walk: Walk | None = None) -> Judged | None:
    """The reading half of `detect_revision`: every verdict computed, nothing stored.

    None when there is nothing to store: no such revision, or ingested executions none of whose
    samples can be read any more (pruned), whose stored results are kept (nothing is not a new
    verdict). ``walk``: a re-analysis's memory of the earlier revisions, brought up to date.
    """
    revision = session.get(Revision, revision_id)
    if revision is None:
        return None
    if walk is not None:
        walk.check(session, revision.component_id)
    candidate, read, executions = read_samples(session, revision.id)
    if executions and not read:
        log.warning(
            "revision %s: the samples of its %d executions are gone (pruned?); "
            "its stored results are kept",
            revision_id,
            len(executions),
        )
        if walk is not None:
            walk.kept(session, revision_id)
        return None
    config = component_config(session, revision.component_id)
    if walk is not None and walk.usable and config.window != walk.window:
        walk.disable(f"component {revision.component_id}: its window changed")
    memory = walk if walk is not None and walk.usable else None
    rows, changes = analyze(session, revision, config, candidate, memory)
    if walk is not None:
        walk.judged(session, revision.id, candidate, rows, complete=read == len(executions))
    return Judged(revision.id, rows, changes, executions)


def _lock(session: Session, revision_id: int) -> None:
    """Detections of one revision take turns: a lock for the transaction."""
    session.execute(select(func.pg_advisory_xact_lock(DETECT_LOCK, revision_id)))


def store_judged(database_url: str, judged: Judged, durable: bool = True) -> None:
    """The writing half: replace the revision's results with ``judged``, in one transaction,
    unless the revision's ingested executions changed since it was judged: then it is judged
    again under the lock and that is stored.

    A re-analysis passes ``durable=False``: its commits do not wait for the WAL flush (a crash
    can lose the last few revisions' verdicts, never half of one, and the retried task
    recomputes them all).
    """
    with session_scope(database_url) as session:
        if not durable:
            session.execute(text("SET LOCAL synchronous_commit TO OFF"))
        _lock(session, judged.revision_id)
        revision = session.get(Revision, judged.revision_id)
        if revision is None:
            return
        if tuple(i for i, _ in _ingested(session, revision.id)) != judged.executions:
            # an execution was ingested since: judged again from what is stored now, so a
            # detection of the newer data is never overwritten by verdicts on the older
            fresh = judge_revision(session, revision.id)
            if fresh is None:
                return
            judged = fresh
        store(session, revision, judged.rows, judged.changes)


def detect_revision(database_url: str, revision_id: int) -> list[KsChange]:
    """Run the component's methods on every series of the revision, replacing earlier results.

    Returns KS's changes (a series without a baseline has none; its detections say "not
    enough data: missing baseline"). Reading and storing happen under the revision's lock, in
    one transaction; a revision whose samples were all pruned keeps its stored results.
    """
    with session_scope(database_url) as session:
        _lock(session, revision_id)
        judged = judge_revision(session, revision_id)
        if judged is None:
            return []
        store(session, session.get_one(Revision, revision_id), judged.rows, judged.changes)
        return judged.changes
