"""The MCAP file's own bytes, below what a recording holds (`redline.recording.reader`): its
records as the mcap library streams them, a chunk's records decompressed, the layout of a record
and a message that the reader parses in place, and the magic every MCAP file begins with."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from contextlib import suppress
from pathlib import Path
from typing import Any

from mcap.opcode import Opcode
from mcap.records import Chunk
from mcap.stream_reader import StreamReader

#: how every MCAP file begins (the MCAP specification's magic)
MAGIC = b"\x89MCAP0\r\n"
RECORD = struct.Struct("<BQ")  # opcode, length
CHANNEL_ID = struct.Struct("<H")
LOG_TIME = struct.Struct("<Q")  # after the channel id (u16) and the sequence (u32)
MESSAGE_HEAD = 22  # channel id u16, sequence u32, log time u64, publish time u64
#: the records a chunk may hold (the MCAP specification)
IN_CHUNK = frozenset((Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE))
#: the most one chunk may unpack to: Redline's writer closes a chunk past 1 MiB, so only a
#: message larger than that makes a larger one (a map, a point cloud)
MAX_CHUNK_BYTES = 256 * 1024**2
#: the most an upload's chunks may unpack to in all (the server's ``REDLINE_MAX_UNPACKED_BYTES``,
#: its upload check's only): 16 GiB, twice a throughput test's two minutes of 64 KiB messages
#: at 1 kHz, which the recorder keeps whole (`Message.raw`'s zeros pack to almost nothing)
MAX_UNPACKED_BYTES = 16 * 1024**3


class TooLarge(ValueError):
    """A recording whose chunks unpack to more than the reader may unpack: not damaged, too
    large for the limit."""


def _size(count: int) -> str:
    return f"{count / 1024**3:g} GiB" if count >= 1024**3 else f"{count / 1024**2:g} MiB"


class Unpacked:
    """What a recording's chunks unpack to, counted as they are unpacked: a chunk is unpacked
    before its records are read, so a few kilobytes that unpack to gigabytes (an upload of any
    host holding a job) would otherwise hold the server's memory; each chunk to at most
    `MAX_CHUNK_BYTES` and to the size it declares, all of them to ``limit`` bytes (None: no
    limit, for recordings the server already took, and one's own)."""

    def __init__(self, limit: int | None) -> None:
        self.limit, self.total = limit, 0

    def chunk(self, chunk: Chunk) -> bytes:
        """The chunk's records, decompressed, or ValueError naming the bound it broke."""
        declared = chunk.uncompressed_size
        if declared > MAX_CHUNK_BYTES:
            raise ValueError(
                f"a chunk declares {declared} bytes unpacked, more than the {MAX_CHUNK_BYTES} "
                "a chunk may hold"
            )
        if self.limit is not None and self.total + declared > self.limit:
            raise TooLarge(
                f"unpacks to more than {_size(self.limit)}, the server's limit "
                "(REDLINE_MAX_UNPACKED_BYTES)"
            )
        data = _decompressed(chunk.compression, chunk.data, declared)
        if len(data) != declared:
            raise ValueError(
                f"a chunk unpacks to {'more' if len(data) > declared else len(data)} bytes, "
                f"not the {declared} it declares"
            )
        self.total += declared
        return data


def _decompressed(compression: str, data: bytes, declared: int) -> bytes:
    """At most ``declared`` + 1 bytes of ``data`` decompressed: one more tells a chunk that
    holds more than it declares."""
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        with zstandard.ZstdDecompressor().stream_reader(data) as reader:
            parts, wanted = [], declared + 1
            while wanted > 0 and (part := reader.read(wanted)):
                parts.append(part)
                wanted -= len(part)
        return b"".join(parts)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=declared + 1)
    raise ValueError(f"a chunk is compressed with {compression!r}, which Redline does not read")


def records(path: Path) -> Iterator[Any]:
    with open(path, "rb") as stream:
        yield from StreamReader(stream, skip_magic=False, emit_chunks=True).records


def chunk_records(data: bytes) -> Iterator[tuple[int, int, int]]:
    """Each record of a chunk's records (``data``, unpacked) as (opcode, where its content
    begins, its length). A chunk holds schemas, channels and messages only, each within it:
    anything else is damage, a ValueError (a chunk of zeros would otherwise be walked nine bytes
    at a time)."""
    position, end = 0, len(data)
    while position < end:
        if position + RECORD.size > end:
            raise ValueError(f"a chunk ends inside a record's header, at byte {position}")
        opcode, length = RECORD.unpack_from(data, position)
        position += RECORD.size
        if opcode not in IN_CHUNK or length > end - position:
            raise ValueError(
                f"a chunk holds a record (opcode {opcode:#04x}, {length} bytes at byte "
                f"{position - RECORD.size}) that is not a schema, channel or message within it"
            )
        yield opcode, position, length
        position += length


def begins_as_mcap(path: Path) -> bool:
    """Whether the file begins with MCAP's magic (False when it cannot be read)."""
    with suppress(OSError), path.open("rb") as file:
        return file.read(len(MAGIC)) == MAGIC
    return False
