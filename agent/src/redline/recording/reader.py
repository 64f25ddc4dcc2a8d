"""Reading a Redline recording back.

One pass over the file with MCAP's stream reader, so that a file cut off before it was finished
still yields every complete chunk it holds (``strict=False``); ``strict=True`` is for accepting an
upload, and refuses anything that is not a finished Redline recording.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.records import Channel, Footer, Header, Message, Metadata
from mcap.stream_reader import StreamReader
from redline.recording.format import (
    COUNTERS_PREFIX,
    DRIVER_PREFIX,
    MARKERS_KEY,
    META_RUN,
    PROFILE,
    SeriesKey,
    canonical_params,
)


class RecordingError(ValueError):
    """A file that is not a (complete) Redline recording; the message says what is wrong."""


@dataclass(frozen=True)
class Segment:
    """One run of one phase for one parameter set, between its begin and end markers."""

    case: str
    phase: str
    params: dict[str, Any]
    warmup: bool
    begin_ns: int
    end_ns: int


@dataclass
class Recording:
    path: Path
    complete: bool = False
    profile: str = ""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    markers: list[dict[str, Any]] = field(default_factory=list)
    counters: list[dict[str, Any]] = field(default_factory=list)
    driver: list[dict[str, Any]] = field(default_factory=list)
    traffic: Counter[str] = field(default_factory=Counter)
    problem: str = ""

    @property
    def run(self) -> dict[str, str]:
        return self.metadata.get(META_RUN, {})

    def segments(self) -> list[Segment]:
        """Pair each begin marker with the next end marker of the same case, phase and params."""
        open_: dict[tuple[str, str, str], dict[str, Any]] = {}
        done: list[Segment] = []
        for marker in sorted(self.markers, key=lambda m: m["t_ns"]):
            ident = (marker["case"], marker["phase"], canonical_params(marker["params"]))
            if marker["event"] == "begin":
                open_[ident] = marker
            elif marker["event"] == "end" and ident in open_:
                begin = open_.pop(ident)
                done.append(Segment(
                    case=marker["case"], phase=marker["phase"], params=marker["params"],
                    warmup=bool(begin.get("warmup")), begin_ns=begin["t_ns"], end_ns=marker["t_ns"],
                ))
        return done

    def series_samples(self, *, include_warmup: bool = False) -> dict[SeriesKey, list[float]]:
        """Counter samples grouped by series, in time order; warm-up phases are left out."""
        timeline = self.series_timeline(include_warmup=include_warmup)
        return {key: [value for _, value in points] for key, points in timeline.items()}

    def series_timeline(self, *, include_warmup: bool = False
                        ) -> dict[SeriesKey, list[tuple[int, float]]]:
        """Like `series_samples`, with each sample's time: ``(t_ns, value)`` pairs."""
        segments = [s for s in self.segments() if include_warmup or not s.warmup]
        segments.sort(key=lambda s: s.begin_ns)
        points: dict[SeriesKey, list[tuple[int, float]]] = {}
        counters = sorted(self.counters, key=lambda c: c["t_ns"])
        index = 0
        for segment in segments:
            params = canonical_params(segment.params)
            while index < len(counters) and counters[index]["t_ns"] < segment.begin_ns:
                index += 1
            cursor = index
            while cursor < len(counters) and counters[cursor]["t_ns"] <= segment.end_ns:
                sample = counters[cursor]
                for counter, value in sample["values"].items():
                    if value is None:
                        continue
                    key = SeriesKey(segment.case, segment.phase, params, sample["process"], counter)
                    points.setdefault(key, []).append((sample["t_ns"], float(value)))
                cursor += 1
        return points


def _records(path: Path) -> Iterator[Any]:
    with open(path, "rb") as stream:
        yield from StreamReader(stream, skip_magic=False).records


def read_recording(path: str | Path, *, strict: bool = True) -> Recording:
    """Read a recording; with ``strict``, raise RecordingError unless it is a finished one."""
    path = Path(path)
    recording = Recording(path=path)
    channels: dict[int, str] = {}
    try:
        for record in _records(path):
            if isinstance(record, Header):
                recording.profile = record.profile
            elif isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                _take_message(recording, channels.get(record.channel_id, ""), record.data)
            elif isinstance(record, Metadata):
                recording.metadata[record.name] = dict(record.metadata)
            elif isinstance(record, Footer):
                recording.complete = True
    except Exception as exc:  # the mcap library raises several types for a damaged file
        recording.problem = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    if strict:
        _check_strict(recording)
    return recording


def _take_message(recording: Recording, topic: str, data: bytes) -> None:
    if topic.startswith(COUNTERS_PREFIX):
        recording.counters.append(json.loads(data))
    elif topic == MARKERS_KEY:
        recording.markers.append(json.loads(data))
    elif topic.startswith(DRIVER_PREFIX):
        recording.driver.append(json.loads(data))
    else:
        recording.traffic[topic] += 1


def _check_strict(recording: Recording) -> None:
    name = recording.path.name
    if recording.problem and not recording.profile:
        raise RecordingError(f"{name} is not an MCAP file ({recording.problem})")
    if recording.problem or not recording.complete:
        detail = recording.problem or "no footer"
        raise RecordingError(f"{name} is truncated or damaged: {detail}")
    if recording.profile != PROFILE:
        raise RecordingError(f"{name} is an MCAP file but not a Redline recording "
                             f"(profile {recording.profile!r}, expected {PROFILE!r})")
    if META_RUN not in recording.metadata:
        raise RecordingError(f"{name} has no {META_RUN!r} metadata")
