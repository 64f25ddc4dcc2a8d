"""Ingestion's public half: an execution's samples become its series, summaries (Postgres) and
the Parquet side table beside its file.

One path for every way data arrives: the worker's ingestion of an uploaded recording
(`redline.worker.ingest`) and an import of results (`redline.server.services.imports`) both
end in `store_samples`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from redline.detect.counters import left_out
from redline.detect.summary import summarize
from redline.recording import SeriesKey
from redline.server.models import Execution, Series, Summary
from redline.server.schemas.fields import MEASURABLE, one_line
from redline.server.services.errors import Unstorable
from redline.server.storage import DISTURBED, NOT_JUDGED, samples_path
from sqlalchemy import delete, select
from sqlalchemy.dialects.postgresql import insert
from sqlalchemy.orm import Session

Samples = dict[SeriesKey, list[float]]
#: series rows per INSERT: Postgres takes at most 65,535 parameters a statement, six a series
#: (an import of 20,000 series was answered "database unavailable", a 503 no retry could help)
SERIES_PER_INSERT = 5_000


#: a series' case, phase, parameters, process and counter together, in UTF-8 bytes: Postgres
#: indexes at most 2,704 bytes a row, and an import of 80 parameters was answered "the database
#: is unavailable" (a 503 no retry could help)
SERIES_KEY_BYTES = 2_000
#: a series' case, phase, process and counter each, in characters (their columns' length)
NAME_LENGTH = 200


def series_ids(session: Session, component_id: int, keys: list[SeriesKey]) -> dict[SeriesKey, int]:
    """Create the series named that do not exist yet (race-free); return every key's id.
    `Unstorable` names the first key that cannot be stored (`_unstorable`)."""
    for key in keys:
        if (why := _unstorable(key)) is not None:
            label = f"{key.case}/{key.phase}[{key.params}] {key.process}.{key.counter}"
            raise Unstorable(f"series {label[:80]!r}...{why}")
    if keys:
        rows = [
            dict(
                component_id=component_id,
                case=k.case,
                phase=k.phase,
                params=k.params,
                process=k.process,
                counter=k.counter,
            )
            for k in keys
        ]
        for start in range(0, len(rows), SERIES_PER_INSERT):
            chunk = rows[start : start + SERIES_PER_INSERT]
            session.execute(insert(Series).values(chunk).on_conflict_do_nothing())
    known = session.scalars(select(Series).where(Series.component_id == component_id))
    by_key = {SeriesKey(s.case, s.phase, s.params, s.process, s.counter): s.id for s in known}
    return {key: by_key[key] for key in keys}


def _unstorable(key: SeriesKey) -> str | None:
    """Why the series cannot be stored (its key over `SERIES_KEY_BYTES`, a name over its
    column's `NAME_LENGTH`, a name or parameter `one_line` refuses, a whole-number parameter
    beyond ±`MEASURABLE`: a recording's names, which no API schema checked), or None."""
    size = len("".join((key.case, key.phase, key.params, key.process, key.counter)).encode())
    if size > SERIES_KEY_BYTES:
        return (
            " is too long to store: its case, phase, parameters, process and counter take "
            f"{size} bytes (at most {SERIES_KEY_BYTES})"
        )
    named = (("case", key.case), ("phase", key.phase), ("process", key.process))
    for what, name in (*named, ("counter", key.counter)):
        if len(name) > NAME_LENGTH:
            return f": its {what} is {len(name)} characters long (at most {NAME_LENGTH})"
    # a NUL failed the insert with a DataError that left the job "uploaded" for good, and a
    # control character broke each line, JUnit report and mail naming the series (an audit)
    params = json.loads(key.params)
    texts = [*named, ("counter", key.counter)]
    if isinstance(params, dict):
        texts += [("parameter name", name) for name in params]
        texts += [(f"parameter {name}", v) for name, v in params.items() if isinstance(v, str)]
    for what, text in texts:
        try:
            one_line(text)
        except ValueError as exc:
            return f": its {what} {exc}"
    if isinstance(params, dict):
        for name, value in params.items():
            number = isinstance(value, int | float) and not isinstance(value, bool)
            if number and abs(value) > MEASURABLE:
                return f": its parameter {name} is beyond ±{MEASURABLE:g}"
    return None


def write_samples(
    path: Path,
    ids: dict[SeriesKey, int],
    samples: Samples,
    not_judged: str | None = None,
    disturbed: Mapping[int, str] | None = None,
) -> None:
    """The side table; in its metadata ``not_judged`` (why none of its samples may be judged)
    and ``disturbed`` (series id → why that series' samples may not)."""
    series = np.concatenate(
        [np.full(len(samples[k]), ids[k], dtype=np.int64) for k in ids]
        or [np.empty(0, dtype=np.int64)]
    )
    values = np.concatenate(
        [np.asarray(samples[k], dtype=np.float64) for k in ids] or [np.empty(0, dtype=np.float64)]
    )
    partial = path.with_suffix(".part")
    table = pa.table({"series_id": series, "value": values})
    meta = {}
    if not_judged is not None:
        meta[NOT_JUDGED] = not_judged.encode()
    if disturbed:
        meta[DISTURBED] = json.dumps({str(k): v for k, v in disturbed.items()}).encode()
    if meta:
        table = table.replace_schema_metadata(meta)
    pq.write_table(table, partial)
    os.replace(partial, path)


def store_samples(
    session: Session,
    execution: Execution,
    component_id: int,
    samples: Samples,
    not_judged: str | None = None,
    disturbed: Mapping[tuple[str, str, str], str] | None = None,
) -> int:
    """The execution's series, summaries and side table, replacing any it had (idempotent);
    how many series got a summary.

    A series without a finite sample gets no summary (its samples stay for detection to name
    the fault). ``not_judged``: the run must not be judged (the component took no part): its
    samples are kept, but no series gets a summary, so it makes no trend point and no baseline.
    ``disturbed``: (case, phase, params) → why: the series of those segments are summarized and
    charted, but not judged in this execution (`redline.recording.disturbance`); their summaries
    say so (``disturbed``), and confirmation leaves them out. What a component's processes hold
    (`counters.is_held`: memory, files) is judged all the same; left out as busy, a leak found
    while a test suite loaded the host had its confirmation pairs run a second time. Its threads
    and address space, which other load can move, are left out as busy (`counters.left_out`).
    """
    samples = {key: values for key, values in samples.items() if len(values)}
    ids = series_ids(session, component_id, sorted(samples))
    session.execute(delete(Summary).where(Summary.execution_id == execution.id))
    summaries = {key: summarize(np.asarray(samples[key], dtype=np.float64)) for key in ids}
    bad = {ids[key]: why for key, why in left_out(ids, disturbed or {}).items()}
    rows = [
        Summary(execution_id=execution.id, series_id=ids[key], disturbed=ids[key] in bad, **stats)
        for key, stats in summaries.items()
        if stats is not None and not_judged is None
    ]
    session.add_all(rows)
    write_samples(samples_path(execution.recording_path), ids, samples, not_judged, bad)
    return len(rows)
