"""The MCAP file's own bytes, below what a recording holds (`redline.recording.reader`): its
records as the mcap library streams them, a chunk's records decompressed, the layout of a record
and a message that the reader parses in place, and the magic every MCAP file begins with."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from contextlib import suppress
from pathlib import Path
from typing import Any

from mcap.records import Chunk
from mcap.stream_reader import StreamReader

#: how every MCAP file begins (the MCAP specification's magic)
MAGIC = b"\x89MCAP0\r\n"
RECORD = struct.Struct("<BQ")  # opcode, length
CHANNEL_ID = struct.Struct("<H")
LOG_TIME = struct.Struct("<Q")  # after the channel id (u16) and the sequence (u32)
MESSAGE_HEAD = 22  # channel id u16, sequence u32, log time u64, publish time u64


def records(path: Path) -> Iterator[Any]:
    with open(path, "rb") as stream:
        yield from StreamReader(stream, skip_magic=False, emit_chunks=True).records


def chunk_data(chunk: Chunk) -> bytes | None:
    """A chunk's records, decompressed; None for a compression only mcap itself knows."""
    if chunk.compression == "zstd":
        import zstandard

        return zstandard.decompress(chunk.data, chunk.uncompressed_size)
    return chunk.data if chunk.compression == "" else None


def begins_as_mcap(path: Path) -> bool:
    """Whether the file begins with MCAP's magic (False when it cannot be read)."""
    with suppress(OSError), path.open("rb") as file:
        return file.read(len(MAGIC)) == MAGIC
    return False
