"""Writing a Redline recording."""

from __future__ import annotations

import json
import struct
import time
from pathlib import Path
from typing import Any, BinaryIO

from mcap._chunk_builder import ChunkBuilder
from mcap.records import Message, MessageIndex
from mcap.writer import CompressionType, Writer
from redline.recording.format import (
    COUNTERS_PREFIX,
    FORMAT_VERSION,
    JSON_ENCODING,
    LOG_ATTACHMENT_PREFIX,
    LOG_KEEP_BYTES,
    MARKERS_KEY,
    PROFILE,
)

_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, two times
_MESSAGE_OPCODE, _MESSAGE_FIELDS = 0x05, 22


class _LeanChunkBuilder(ChunkBuilder):
    """mcap's chunk builder with a message record packed in one call instead of seven.

    The same bytes and message index as mcap's; it halves the cost of a message (~8 to ~4 us,
    measured), which is what lets the recorder keep up with 100,000 samples/s.
    """

    def add_message(self, message: Message) -> None:
        log_time, channel_id, data = message.log_time, message.channel_id, message.data
        if self.num_messages == 0 or log_time < self.message_start_time:
            self.message_start_time = log_time
        self.message_end_time = max(self.message_end_time, log_time)
        index = self.message_indices.get(channel_id)
        if index is None:
            index = self.message_indices[channel_id] = MessageIndex(channel_id, records=[])
        buffer = self.record_writer._buffer
        index.records.append((log_time, buffer.tell()))
        buffer.write(
            _MESSAGE_HEAD.pack(
                _MESSAGE_OPCODE,
                _MESSAGE_FIELDS + len(data),
                channel_id,
                message.sequence,
                log_time,
                message.publish_time,
            )
        )
        buffer.write(data)
        self.num_messages += 1


def _use_lean_chunks(writer: Writer) -> None:
    """Swap in the lean builder where this mcap version has the one it replaces (else keep it)."""
    if type(getattr(writer, "_Writer__chunk_builder", None)) is ChunkBuilder:
        writer._Writer__chunk_builder = _LeanChunkBuilder()  # type: ignore[attr-defined]


def _strings(data: dict[str, Any]) -> dict[str, str]:
    return {
        str(key): value if isinstance(value, str) else json.dumps(value, default=str)
        for key, value in data.items()
    }


class RecordingWriter:
    """Appends messages to one MCAP file; one channel per topic, registered on first use.

    Not thread-safe: the recorder feeds it from a single writer thread.
    """

    def __init__(
        self, path: str | Path, *, library: str = "redline", chunk_size: int = 1 << 20
    ) -> None:
        self.path = Path(path)
        self._stream: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._stream, compression=CompressionType.ZSTD, chunk_size=chunk_size)
        _use_lean_chunks(self._writer)
        self._writer.start(profile=PROFILE, library=f"{library} (format {FORMAT_VERSION})")
        self._channels: dict[str, int] = {}
        self._sequence = 0
        self.messages = 0
        self._closed = False

    def _channel(self, topic: str, encoding: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._writer.register_channel(topic, encoding or "", 0, {})
            self._channels[topic] = channel
        return channel

    def write(
        self, topic: str, data: bytes, *, encoding: str = "", t_ns: int | None = None
    ) -> None:
        """Write one message; ``t_ns`` is its log time (now if not given)."""
        stamp = time.time_ns() if t_ns is None else t_ns
        self._sequence += 1
        self._writer.add_message(
            self._channel(topic, encoding),
            log_time=stamp,
            data=data,
            publish_time=stamp,
            sequence=self._sequence,
        )
        self.messages += 1

    def write_json(self, topic: str, obj: dict[str, Any]) -> None:
        """Write a JSON message; its log time is ``obj["t_ns"]`` when present."""
        self.write(topic, json.dumps(obj).encode(), encoding=JSON_ENCODING, t_ns=obj.get("t_ns"))

    def counters(self, process: str, pid: int, values: dict[str, float], t_ns: int) -> None:
        self.write_json(
            COUNTERS_PREFIX + process,
            {"t_ns": t_ns, "pid": pid, "process": process, "values": values},
        )

    def marker(
        self,
        event: str,
        case: str,
        phase: str,
        params: dict[str, Any],
        *,
        warmup: bool = False,
        t_ns: int | None = None,
    ) -> None:
        self.write_json(
            MARKERS_KEY,
            {
                "t_ns": time.time_ns() if t_ns is None else t_ns,
                "event": event,
                "case": case,
                "phase": phase,
                "params": params,
                "warmup": warmup,
            },
        )

    def metadata(self, name: str, data: dict[str, Any]) -> None:
        self._writer.add_metadata(name, _strings(data))

    def log(self, process: str, output: bytes, cut: int = 0) -> None:
        """Attach a process's output as ``log/<process>``: its last `LOG_KEEP_BYTES`, with a
        first line saying how much was left out (``cut`` bytes before ``output`` began, and
        whatever of ``output`` is beyond the limit)."""
        if len(output) > LOG_KEEP_BYTES:
            cut += len(output) - LOG_KEEP_BYTES
            output = output[-LOG_KEEP_BYTES:]
        if cut:
            output = f"[... the first {cut} bytes are not kept ...]\n".encode() + output
        now = time.time_ns()
        self._writer.add_attachment(
            create_time=now,
            log_time=now,
            name=LOG_ATTACHMENT_PREFIX + process,
            media_type="text/plain",
            data=output,
        )

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._writer.finish()
        self._stream.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
