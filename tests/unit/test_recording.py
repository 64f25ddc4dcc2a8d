"""Recordings without a run: the lean chunk builder writes what mcap would, and a cut-off file
is refused by strict reading and replayed up to its cut by lenient reading."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader
from redline.recording import RecordingError, RecordingWriter, read_recording
from redline.recording import writer as writer_module


def _write(path: Path) -> Path:
    with RecordingWriter(path) as writer:
        for index in range(3000):  # several chunks, three channels, two encodings
            writer.write(
                f"robot/{index % 3}",
                bytes([index % 251]) * (index % 700),
                encoding="zenoh/bytes" if index % 3 else "json",
                t_ns=1000 + index,
            )
        writer.metadata("redline.run", {"component": "c"})
    return path


def test_lean_chunk_builder_writes_the_same_bytes_as_mcaps_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    lean = _write(tmp_path / "lean.mcap")
    monkeypatch.setattr(writer_module, "_use_lean_chunks", lambda writer: None)
    plain = _write(tmp_path / "plain.mcap")
    assert lean.read_bytes() == plain.read_bytes()
    with open(lean, "rb") as stream:  # and mcap's indexed reader finds every message by topic
        reader = make_reader(stream)
        assert sum(1 for _ in reader.iter_messages(topics=["robot/1"])) == 1000


def test_replay_of_a_cut_off_recording_replays_what_it_holds(tmp_path: Path) -> None:
    from redline.testing.replay import load_recorded

    full_path = tmp_path / "full.mcap"
    with RecordingWriter(full_path, chunk_size=512) as writer:  # many small chunks
        for index in range(300):
            writer.write("robot/scan", f"scan {index:04d}".encode() * 8, t_ns=1_000 + index)
        writer.metadata("redline.run", {"component": "x"})
    full = load_recorded(full_path)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full_path.read_bytes()[: full_path.stat().st_size // 2])
    kept = load_recorded(cut)  # never an error: the chunks before the cut survive
    assert len(full) == 300
    assert 0 < len(kept) < len(full)
    assert kept == full[: len(kept)]


def test_strict_reading_refuses_a_cut_off_file_and_lenient_reading_keeps_its_prefix(
    tmp_path: Path,
) -> None:
    full_path = tmp_path / "full.mcap"
    with RecordingWriter(full_path, chunk_size=512) as writer:
        for index in range(300):
            writer.counters("component", 1, {"cpu_percent": float(index)}, 1_000 + index)
        writer.metadata("redline.run", {"component": "x"})
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full_path.read_bytes()[: full_path.stat().st_size // 2])
    with pytest.raises(RecordingError, match="truncated"):
        read_recording(cut)
    kept = read_recording(cut, strict=False)
    values = [sample["values"]["cpu_percent"] for sample in kept.counters]
    assert not kept.complete and 0 < len(values) < 300
    assert values == [float(index) for index in range(len(values))]


def test_a_process_log_is_attached_and_only_its_end_kept_when_long(tmp_path: Path) -> None:
    from redline.recording.format import LOG_KEEP_BYTES

    path = tmp_path / "logs.mcap"
    long = b"".join(b"line %d\n" % i for i in range(60_000))  # about 0.5 MB
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", {"component": "c"})
        writer.log("c", b"ready\n\xff not utf-8\n")
        writer.log("chatty", long[1000:], cut=1000)
    recording = read_recording(path)
    assert recording.logs["c"] == "ready\n\ufffd not utf-8\n"
    first, rest = recording.logs["chatty"].split("\n", 1)
    assert first == f"[... the first {len(long) - LOG_KEEP_BYTES} bytes are not kept ...]"
    assert rest.encode() == long[-LOG_KEEP_BYTES:]
    with open(path, "rb") as stream:  # standard MCAP attachments, for any MCAP tool
        names = [a.name for a in make_reader(stream).iter_attachments()]
    assert names == ["log/c", "log/chatty"]


def _chunk(compression: str, data: bytes, declared: int):  # noqa: ANN202
    from mcap.records import Chunk

    return Chunk(
        compression=compression,
        data=data,
        message_end_time=0,
        message_start_time=0,
        uncompressed_crc=0,
        uncompressed_size=declared,
    )


def _peak_and_error(action) -> tuple[int, Exception | None]:  # noqa: ANN001
    """The most memory ``action()`` held at once, and what it raised."""
    import tracemalloc

    tracemalloc.start()
    try:
        action()
    except Exception as exc:  # noqa: BLE001 - the test asserts on it
        return tracemalloc.get_traced_memory()[1], exc
    finally:
        tracemalloc.stop()
    return tracemalloc.get_traced_memory()[1], None


def test_a_recording_that_unpacks_beyond_its_limit_is_refused_before_it_is_unpacked(
    tmp_path: Path,
) -> None:
    """Any host holding a job uploads a recording the server reads at once: a few kilobytes
    that unpack to gigabytes held its memory. Here 40 MiB of zeros in one chunk (a 4 KiB file)
    against a limit of 8 MiB: refused, naming the limit, without unpacking it."""
    path = tmp_path / "bomb.mcap"
    with RecordingWriter(path) as writer:
        writer.write("robot/scan", bytes(40 * 1024**2), t_ns=1_000)
        writer.metadata("redline.run", {"component": "x"})
    assert path.stat().st_size < 64 * 1024
    peak, error = _peak_and_error(lambda: read_recording(path, max_unpacked=8 * 1024**2))
    assert isinstance(error, RecordingError)
    assert "bomb.mcap unpacks to more than 8 MiB, the server's limit" in str(error)
    assert "REDLINE_MAX_UNPACKED_BYTES" in str(error) and peak < 4 * 1024**2
    # not damaged: too large for that limit, and read where none is set (the server's own
    # stored recordings, one's own)
    assert "damaged" not in str(error)
    assert read_recording(path).traffic["robot/scan"] == 1


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_a_chunk_that_unpacks_to_more_than_it_declares_is_refused_without_unpacking_it(
    compression: str,
) -> None:
    import lz4.frame
    import zstandard
    from redline.recording.mcap_bytes import Unpacked

    zeros = bytes(64 * 1024**2)
    packed = (zstandard.compress if compression == "zstd" else lz4.frame.compress)(zeros)
    unpacked = Unpacked(1024**4)
    # the frame says how large it is: the library alone would unpack all of it
    peak, error = _peak_and_error(lambda: unpacked.chunk(_chunk(compression, packed, 1)))
    assert "unpacks to more bytes, not the 1 it declares" in str(error) and peak < 16 * 1024**2
    with pytest.raises(ValueError, match="declares 1099511627776 bytes unpacked, more than"):
        unpacked.chunk(_chunk(compression, packed, 1024**4))
    assert unpacked.chunk(_chunk(compression, packed, len(zeros))) == zeros


def test_a_chunk_of_anything_but_schemas_channels_and_messages_is_damage() -> None:
    from redline.recording.mcap_bytes import chunk_records

    with pytest.raises(ValueError, match=r"opcode 0x00, 0 bytes at byte 0\) that is not"):
        list(chunk_records(bytes(1024)))
    message = bytes([0x05]) + (30).to_bytes(8, "little")  # a message 30 bytes long, cut at 10
    with pytest.raises(ValueError, match="opcode 0x05, 30 bytes at byte 0"):
        list(chunk_records(message + bytes(10)))
    with pytest.raises(ValueError, match="ends inside a record's header, at byte 39"):
        list(chunk_records(message + bytes(30) + b"\x05"))
    assert list(chunk_records(message + bytes(30))) == [(0x05, 9, 30)]
