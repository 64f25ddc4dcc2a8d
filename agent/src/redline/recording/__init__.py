"""Redline's recording format: one MCAP file per execution, the contract between agent and server.

See `format.py` for the channel and metadata layout, `writer.py` to write one, and `reader.py` to
read one back (strictly for validation, or leniently to recover what a cut-off file holds).
"""

from redline.recording.format import (
    COUNTERS_PREFIX,
    DRIVER_PREFIX,
    HOST_PROCESS,
    MARKERS_KEY,
    REDLINE_PREFIX,
    SeriesKey,
    canonical_params,
    params_name,
)
from redline.recording.reader import Recording, RecordingError, Segment, read_recording
from redline.recording.writer import RecordingWriter

__all__ = [
    "COUNTERS_PREFIX",
    "DRIVER_PREFIX",
    "HOST_PROCESS",
    "MARKERS_KEY",
    "REDLINE_PREFIX",
    "Recording",
    "RecordingError",
    "RecordingWriter",
    "Segment",
    "SeriesKey",
    "canonical_params",
    "params_name",
    "read_recording",
]
