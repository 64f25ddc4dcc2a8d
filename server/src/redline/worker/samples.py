"""A revision's samples, read from the Parquet side tables ingestion writes beside each recording,
and a cache of them (with the values each detector level makes of them) for a walk in order."""

from __future__ import annotations

import logging
from collections import Counter, defaultdict
from typing import NamedTuple

import numpy as np
import pyarrow.parquet as pq
from redline.detect.execution_shift import values_for
from redline.detect.methods import Levelled
from redline.server.models import (
    Execution,
)
from redline.server.services.reach import ingested_executions
from redline.server.storage import disturbed_series, not_judged, samples_path
from sqlalchemy import select
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)


#: Per series id, one array of samples per execution (in execution order).
Samples = dict[int, list[np.ndarray]]


def ingested_runs(session: Session, revision_id: int) -> list[tuple[int, str]]:
    """(id, recording path) of the revision's ingested executions, in execution order."""
    return [
        (execution_id, path)
        for execution_id, path in session.execute(
            select(Execution.id, Execution.recording_path)
            .where(Execution.revision_id == revision_id, Execution.id.in_(ingested_executions()))
            .order_by(Execution.id)
        )
    ]


class RevisionSamples(NamedTuple):
    """What `read_samples` read of a revision."""

    samples: Samples
    read: int  # the executions whose side tables were read
    executions: tuple[int, ...]  # the ids of the revision's ingested executions
    #: the series only executions not to be judged hold, with the reason
    unjudged: dict[int, str]
    #: the series judged on fewer executions than were read, saying how many lacked them
    partial: dict[int, str]


def read_samples(session: Session, revision_id: int) -> RevisionSamples:
    """Every ingested sample of the revision, per series id and execution; with how many of
    its ingested executions' side tables were read, the ids of those executions, and the
    series of those whose samples must not be judged, each with the reason: a run the
    component took no part in (`not_judged`), a phase the host was busy in (`disturbed_series`).
    A series judged on only some of the executions (the others lacked it, or were busy in its
    phase) is in ``partial``, saying so: "1 of 3 executions lacked this series".

    A side table that is gone (pruned) is left out with a warning: its series then lack data.
    """
    executions = ingested_runs(session, revision_id)
    samples: Samples = defaultdict(list)
    unjudged: dict[int, str] = {}
    busy_runs: Counter[int] = Counter()
    read = judged_runs = 0
    for _, path in executions:
        try:
            table = pq.read_table(samples_path(path), columns=["series_id", "value"])
        except OSError as exc:
            log.warning("revision %s: samples of %s unreadable: %s", revision_id, path, exc)
            continue
        read += 1
        series = table.column("series_id").to_numpy()
        reason = not_judged(table)
        if reason is not None:  # a run the component took no part in: never a candidate
            unjudged.update(dict.fromkeys(np.unique(series).tolist(), reason))
            continue
        judged_runs += 1
        values = table.column("value").to_numpy()
        order = np.argsort(series, kind="stable")
        ids, starts = np.unique(series[order], return_index=True)
        busy = disturbed_series(table)
        for series_id, chunk in zip(ids.tolist(), np.split(values[order], starts[1:]), strict=True):
            if series_id in busy:  # measured while the host was busy: not this execution's say
                unjudged.setdefault(series_id, busy[series_id])
                busy_runs[series_id] += 1
                continue
            samples[series_id].append(chunk)
    partial = {
        series_id: note
        for series_id, chunks in samples.items()
        if (note := _partial(judged_runs, len(chunks), busy_runs[series_id]))
    }
    return RevisionSamples(
        dict(samples),
        read,
        tuple(execution_id for execution_id, _ in executions),
        unjudged,
        partial,
    )


def _partial(runs: int, held: int, busy: int) -> str:
    """Why a series was judged on ``held`` of ``runs`` executions (``busy`` left out for a
    busy host, the rest without it); "" when on all of them."""
    lacked = runs - held - busy
    said = [f"{lacked} of {runs} executions lacked this series"] if lacked > 0 else []
    if busy:
        said.append(f"{busy} of {runs} executions left out (measured while the host was busy)")
    return "; ".join(said)


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
        self, session: Session, revision_id: int, series_id: int, detector: Levelled
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
