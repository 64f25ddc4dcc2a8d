"""Reading a Redline recording back.

One pass over the file with MCAP's stream reader, so that a file cut off before it was finished
still yields every complete chunk it holds (``strict=False``); ``strict=True`` is for accepting an
upload, and refuses anything that is not a finished Redline recording.
"""

from __future__ import annotations

import json
from bisect import bisect_left, bisect_right
from collections import Counter
from dataclasses import dataclass, field
from io import BytesIO
from operator import itemgetter
from pathlib import Path
from statistics import mean
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Footer, Header, Message, Metadata
from redline.recording.disturbance import OTHER_CPU, OTHER_PEAK, other_load, other_peak
from redline.recording.driver import (
    CPU_PER_OP,
    CPU_REFS_PER_OP,
    DRIVER_PROCESS,
    HOST_REFERENCE,
    RECORDER_PROCESS,
    RUN_CASE,
    RUN_PHASE,
    recorder_values,
    report_values,
    segment_of,
    series_name,
    work_done,
)
from redline.recording.format import (
    COUNTERS_PREFIX,
    DRIVER_PREFIX,
    HOST_PROCESS,
    LOG_ATTACHMENT_PREFIX,
    MARKERS_KEY,
    META_HOST,
    META_RECORDER,
    META_RUN,
    OWN_PROCESS,
    PROFILE,
    SeriesKey,
    canonical_params,
)
from redline.recording.mcap_bytes import (
    CHANNEL_ID,
    LOG_TIME,
    MESSAGE_HEAD,
    TooLarge,
    Unpacked,
    begins_as_mcap,
    chunk_records,
    records,
)
from redline.recording.shapes import keep_well_formed


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
    #: with ``read_recording(..., events=True)``: every traffic sample as (key, log time in ns,
    #: payload bytes), in file order (`redline.predict` learns from them)
    events: list[tuple[str, int, int]] | None = None
    #: each component or fixture process's output (its end), by process name
    logs: dict[str, str] = field(default_factory=dict)
    problem: str = ""
    #: the first message not of a shape Redline writes (`redline.recording.shapes`), left out
    malformed: str = ""

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
                done.append(
                    Segment(
                        case=marker["case"],
                        phase=marker["phase"],
                        params=marker["params"],
                        warmup=bool(begin.get("warmup")),
                        begin_ns=begin["t_ns"],
                        end_ns=marker["t_ns"],
                    )
                )
        return done

    def series_samples(self, *, include_warmup: bool = False) -> dict[SeriesKey, list[float]]:
        """Counter samples grouped by series, in time order; warm-up phases are left out."""
        return self._grouped(include_warmup, timed=False)

    def series_timeline(
        self, *, include_warmup: bool = False
    ) -> dict[SeriesKey, list[tuple[int, float]]]:
        """Like `series_samples`, with each sample's time: ``(t_ns, value)`` pairs."""
        return self._grouped(include_warmup, timed=True)

    def _grouped(self, include_warmup: bool, timed: bool) -> dict[SeriesKey, list[Any]]:
        """The monitor's counters per segment with what else used the host in it
        (`recording.disturbance`), then the driver's metrics (`recording.driver`)."""
        every = self.segments()
        cores = _int(self.metadata.get(META_HOST, {}).get("cpu_cores"))
        segments = sorted(
            (s for s in every if include_warmup or not s.warmup), key=lambda s: s.begin_ns
        )
        grouped: dict[SeriesKey, list[Any]] = {}
        counters = sorted(self.counters, key=itemgetter("t_ns"))
        times = [sample["t_ns"] for sample in counters]
        for segment in segments:
            params = canonical_params(segment.params)
            inside = counters[
                bisect_left(times, segment.begin_ns) : bisect_right(times, segment.end_ns)
            ]
            # keyed by a plain tuple while grouping: SeriesKey's hash is Python code, per sample
            by_counter = _by_counter(inside, timed)
            for (process, counter), values in by_counter.items():
                key = SeriesKey(segment.case, segment.phase, params, process, counter)
                grouped.setdefault(key, []).extend(values)
            other = other_load(by_counter, cores)
            if other is not None:
                key = SeriesKey(segment.case, segment.phase, params, HOST_PROCESS, OTHER_CPU)
                grouped.setdefault(key, []).append((segment.end_ns, other) if timed else other)
                peak = other_peak(inside, segment.begin_ns, segment.end_ns, cores)
                if peak is not None:
                    key = SeriesKey(segment.case, segment.phase, params, HOST_PROCESS, OTHER_PEAK)
                    grouped.setdefault(key, []).append((segment.end_ns, peak) if timed else peak)
        self._add_driver(grouped, every, include_warmup, timed)
        return grouped

    def _add_driver(
        self,
        grouped: dict[SeriesKey, list[Any]],
        segments: list[Segment],
        include_warmup: bool,
        timed: bool,
    ) -> None:
        """One value per driver report and field, in its segment; each component's CPU per
        unit of work the driver delivered there; the recorder's run-wide counts in the run's
        own segment (`redline.recording.driver`)."""
        reports: dict[int, tuple[Segment, list[dict[str, Any]]]] = {}  # by the segment's id
        for report in self.driver:
            segment = segment_of(report, segments)
            if segment is None or (segment.warmup and not include_warmup):
                continue  # a report outside any finished segment measured nothing whole
            reports.setdefault(id(segment), (segment, []))[1].append(report)
            params, name, t_ns = (
                canonical_params(segment.params),
                series_name(report),
                int(report.get("t_ns", segment.end_ns)),
            )
            for field_name, value in report_values(report).items():
                key = SeriesKey(
                    segment.case, segment.phase, params, DRIVER_PROCESS, f"{name}:{field_name}"
                )
                grouped.setdefault(key, []).append((t_ns, value) if timed else value)
        for segment, made in reports.values():
            _add_cpu_per_op(grouped, segment, work_done(made), timed)
        end = max((s.end_ns for s in segments), default=0)
        for field_name, value in recorder_values(self.metadata.get(META_RECORDER, {})).items():
            key = SeriesKey(RUN_CASE, RUN_PHASE, canonical_params({}), RECORDER_PROCESS, field_name)
            grouped.setdefault(key, []).append((end, value) if timed else value)


def _int(text: str | None) -> int:
    try:
        return int(text or 0)
    except ValueError:
        return 0


def _add_cpu_per_op(
    grouped: dict[SeriesKey, list[Any]], segment: Segment, work: float, timed: bool
) -> None:
    """Each monitored process's CPU time in the segment per unit of work (µs per sample
    published or query answered), from its mean CPU share over the segment's duration; and,
    where the monitor timed the host's reference work, the same in units of it (its mean time
    over the segment, which the component's CPU followed more closely than the median or the
    fastest did: docs/detection.md; `CPU_REFS_PER_OP`)."""
    if work <= 0:
        return
    params, seconds = canonical_params(segment.params), (segment.end_ns - segment.begin_ns) / 1e9
    timings = grouped.get(
        SeriesKey(segment.case, segment.phase, params, HOST_PROCESS, HOST_REFERENCE)
    )
    reference = mean(v[1] if timed else v for v in timings) if timings else 0.0
    for key in [
        k
        for k in grouped
        if k.counter == "cpu_percent"
        and k.process not in (HOST_PROCESS, OWN_PROCESS)
        and (k.case, k.phase, k.params) == (segment.case, segment.phase, params)
    ]:
        shares = [v[1] if timed else v for v in grouped[key]]
        value = sum(shares) / len(shares) / 100.0 * seconds * 1e6 / work
        derived = {CPU_PER_OP: value} | (
            {CPU_REFS_PER_OP: value / reference} if reference > 0 else {}
        )
        for counter, derived_value in derived.items():
            series = SeriesKey(key.case, key.phase, key.params, key.process, counter)
            grouped.setdefault(series, []).append(
                (segment.end_ns, derived_value) if timed else derived_value
            )


def _by_counter(samples: list[dict[str, Any]], timed: bool) -> dict[tuple[str, str], list[Any]]:
    """One segment's samples grouped by (process, counter), in order; None values left out."""
    grouped: dict[tuple[str, str], list[Any]] = {}
    for sample in samples:
        process, t_ns = sample["process"], sample["t_ns"]
        for counter, value in sample["values"].items():
            if value is None:
                continue
            bucket = grouped.get((process, counter))
            if bucket is None:
                bucket = grouped[(process, counter)] = []
            bucket.append((t_ns, float(value)) if timed else float(value))
    return grouped


def _take_chunk(
    recording: Recording, data: bytes, channels: dict[int, tuple[int, str]], counters: list[bytes]
) -> None:
    """The messages and channels of one chunk's records (``data``, unpacked), parsed in place
    (mcap's reader goes byte by byte, which made reading the file most of an ingest)."""
    for opcode, position, length in chunk_records(data):
        if opcode == Opcode.MESSAGE:
            kind, topic = channels.get(CHANNEL_ID.unpack_from(data, position)[0], (_TRAFFIC, ""))
            if kind == _COUNTERS:
                counters.append(data[position + MESSAGE_HEAD : position + length])
            elif kind == _TRAFFIC:
                recording.traffic[topic] += 1
                if recording.events is not None:
                    stamp = LOG_TIME.unpack_from(data, position + 6)[0]
                    recording.events.append((topic, stamp, length - MESSAGE_HEAD))
            else:
                _take_message(
                    recording, kind, topic, data[position + MESSAGE_HEAD : position + length]
                )
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(ReadDataStream(BytesIO(data[position : position + length])))
            channels[channel.id] = (_kind(channel.topic), channel.topic)


def _take_record(
    recording: Recording, record: Any, channels: dict[int, tuple[int, str]], counters: list[bytes]
) -> None:
    if isinstance(record, Message):
        kind, topic = channels.get(record.channel_id, (_TRAFFIC, ""))
        if kind == _COUNTERS:
            counters.append(record.data)
        else:
            _take_message(recording, kind, topic, record.data)
            if kind == _TRAFFIC and recording.events is not None:
                recording.events.append((topic, record.log_time, len(record.data)))
    elif isinstance(record, Channel):
        channels[record.id] = (_kind(record.topic), record.topic)
    elif isinstance(record, Header):
        recording.profile = record.profile
    elif isinstance(record, Metadata):
        recording.metadata[record.name] = dict(record.metadata)
    elif isinstance(record, Attachment) and record.name.startswith(LOG_ATTACHMENT_PREFIX):
        process = record.name.removeprefix(LOG_ATTACHMENT_PREFIX)
        recording.logs[process] = bytes(record.data).decode(errors="replace")
    elif isinstance(record, Footer):
        recording.complete = True


def read_recording(
    path: str | Path, *, strict: bool = True, events: bool = False, max_unpacked: int | None = None
) -> Recording:
    """Read a recording; with ``strict``, raise RecordingError unless it is a finished one;
    with ``events``, keep every traffic sample's key, time and size (`Recording.events`). Its
    chunks may unpack to ``max_unpacked`` bytes in all (`Unpacked`; None: no limit), else
    RecordingError, strict or not."""
    path = Path(path)
    recording = Recording(path=path, events=[] if events else None)
    channels: dict[int, tuple[int, str]] = {}
    counters: list[bytes] = []  # decoded at the end in one call: JSON per message dominated
    unpacked = Unpacked(max_unpacked)
    try:
        for record in records(path):
            if isinstance(record, Chunk):
                _take_chunk(recording, unpacked.chunk(record), channels, counters)
            else:
                _take_record(recording, record, channels, counters)
    except TooLarge as exc:
        raise RecordingError(f"{path.name} {exc}") from None
    except Exception as exc:  # the mcap library raises several types for a damaged file
        recording.problem = _problem(exc)
    _decode_counters(recording, counters)
    recording.malformed = keep_well_formed(recording.counters, recording.markers, recording.driver)
    if strict:
        _check_strict(recording)
    return recording


_TRAFFIC, _COUNTERS, _MARKERS, _DRIVER = range(4)


def _kind(topic: str) -> int:
    if topic.startswith(COUNTERS_PREFIX):
        return _COUNTERS
    if topic == MARKERS_KEY:
        return _MARKERS
    return _DRIVER if topic.startswith(DRIVER_PREFIX) else _TRAFFIC


def _problem(exc: Exception) -> str:
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def _take_message(recording: Recording, kind: int, topic: str, data: bytes) -> None:
    if kind == _MARKERS:
        recording.markers.append(json.loads(data))
    elif kind == _DRIVER:
        recording.driver.append(json.loads(data))
    else:
        recording.traffic[topic] += 1


def _decode_counters(recording: Recording, raw: list[bytes]) -> None:
    """All counter messages as one JSON array; message by message only to name a bad one."""
    try:
        recording.counters = json.loads(b"[" + b",".join(raw) + b"]") if raw else []
        if len(recording.counters) == len(raw):
            return
    except (ValueError, RecursionError):
        pass
    recording.counters = []
    for number, data in enumerate(raw, 1):
        try:
            recording.counters.append(json.loads(data))
        except (ValueError, RecursionError) as exc:
            problem = f"counter sample {number} is not JSON ({_problem(exc)[:120]})"
            recording.problem = recording.problem or problem
            return


def _check_strict(recording: Recording) -> None:
    name = recording.path.name
    if recording.problem and not recording.profile:
        if not begins_as_mcap(recording.path):  # the library's detail says nothing useful then
            raise RecordingError(
                f"{name} is not an MCAP file (it does not begin as one: a recording is what "
                "`redline run` or an agent writes)"
            )
        raise RecordingError(f"{name} is not an MCAP file ({recording.problem})")
    if recording.problem or not recording.complete:
        detail = recording.problem or "no footer"
        raise RecordingError(f"{name} is truncated or damaged: {detail}")
    if recording.malformed:
        raise RecordingError(
            f"{name} holds a message Redline does not write: {recording.malformed}"
        )
    if recording.profile != PROFILE:
        raise RecordingError(
            f"{name} is an MCAP file but not a Redline recording "
            f"(profile {recording.profile!r}, expected {PROFILE!r})"
        )
    if META_RUN not in recording.metadata:
        raise RecordingError(f"{name} has no {META_RUN!r} metadata")
