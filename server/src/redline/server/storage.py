"""Where the server keeps an execution's files: the recording and its raw samples beside it."""

from __future__ import annotations

from pathlib import Path


def samples_path(recording_path: str | Path) -> Path:
    """The Parquet side table (series_id, value) beside ``x.mcap``: ``x.samples.parquet``.

    Written by ingestion and imports, read by detection and compare, deleted by retention.
    """
    return Path(recording_path).with_suffix(".samples.parquet")
