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
