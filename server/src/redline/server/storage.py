"""Where the server keeps an execution's files: the recording and its raw samples beside it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pyarrow as pa

#: In a side table's schema metadata: why its samples must not be judged, e.g. "no traffic: ..."
#: for a run in which the component took no part (`redline.recording.format.no_traffic_reason`).
NOT_JUDGED = b"redline.not_judged"
#: In a side table's schema metadata: JSON ``{series id: reason}`` of the series measured in a
#: disturbed phase (`redline.recording.disturbance`), not judged in this execution.
DISTURBED = b"redline.disturbed"


def samples_path(recording_path: str | Path) -> Path:
    """The Parquet side table (series_id, value) beside ``x.mcap``: ``x.samples.parquet``.

    Written by ingestion and imports, read by detection and compare, deleted by retention.
    """
    return Path(recording_path).with_suffix(".samples.parquet")


def not_judged(table: pa.Table) -> str | None:
    """Why the side table's samples must not be judged or compared; None when they may."""
    reason = (table.schema.metadata or {}).get(NOT_JUDGED)
    return reason.decode() if reason is not None else None


def disturbed_series(table: pa.Table) -> dict[int, str]:
    """The side table's series measured in a disturbed phase, each with the reason."""
    raw = (table.schema.metadata or {}).get(DISTURBED)
    return {int(series): reason for series, reason in json.loads(raw).items()} if raw else {}
