"""The recorder process: writes everything that crosses the run's zenoh network into one MCAP file.

    python -m redline.agent.recorder --out run.mcap --meta meta.json [--buffer 200000]

Client settings for zenoh come as JSON in ``REDLINE_ZENOH``. Subscribes to ``**`` and, because
``**`` does not match chunks starting with ``@``, to ``@redline/**`` as well. Zenoh callbacks only
append to a bounded queue and count what does not fit (the recorder never back-pressures a
component); one writer thread writes the file. Prints ``redline-recorder ready`` once subscribed,
and answers queries on ``@redline/recorder/status`` with its counts (the runner uses that as a
barrier: a reply means the samples published before it have arrived). On SIGTERM or SIGINT it
drains the queue, writes the run and host metadata found in the ``--meta`` JSON file (read at that
moment, so the runner can add the end time) and the ``redline.recorder`` counts, and finishes.
"""

from __future__ import annotations

import argparse
import collections
import json
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import zenoh
from redline.agent.network import client_settings_from_env, open_client
from redline.recording.format import (
    JSON_ENCODING,
    META_HOST,
    META_RECORDER,
    META_RUN,
    REDLINE_PREFIX,
)
from redline.recording.writer import RecordingWriter

STATUS_KEY = "@redline/recorder/status"
Item = tuple[str, str, bytes, int]


class Tap:
    """The callback of one subscriber: queue the sample or count it as dropped, never block.

    A deque (append is atomic under the GIL, ~0.3 us) rather than a `queue.Queue` (~1.3 us with
    its locks): at 100,000 samples/s the callback's cost is most of the recorder's budget.
    """

    def __init__(self, buffer: collections.deque[Item], capacity: int,
                 skip_redline: bool) -> None:
        self.buffer = buffer
        self.capacity = capacity
        self.skip_redline = skip_redline
        self.received = 0
        self.dropped = 0
        self._encodings: dict[str, str] = {}  # one channel per key: its first encoding

    def __call__(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if self.skip_redline and key.startswith(REDLINE_PREFIX):
            return  # arrives through the @redline/** subscriber, should ** ever match it
        self.received += 1
        if len(self.buffer) >= self.capacity:
            self.dropped += 1
            return
        encoding = self._encodings.get(key)
        if encoding is None:
            encoding = self._encodings[key] = str(sample.encoding)
        self.buffer.append((key, encoding, sample.payload.to_bytes(), time.time_ns()))


class Recorder:
    """Owns the writer thread and the counts."""

    def __init__(self, out: Path, buffer_size: int) -> None:
        self.buffer: collections.deque[Item] = collections.deque()
        self.taps = [Tap(self.buffer, buffer_size, skip_redline=True),
                     Tap(self.buffer, buffer_size, skip_redline=False)]
        self.writer = RecordingWriter(out, library="redline-recorder")
        self.written = 0
        self.closing = threading.Event()
        self.thread = threading.Thread(target=self._write_loop, name="writer", daemon=True)

    def counts(self) -> dict[str, int]:
        return {"received": sum(t.received for t in self.taps), "written": self.written,
                "dropped": sum(t.dropped for t in self.taps)}

    def _write_loop(self) -> None:
        while not (self.closing.is_set() and not self.buffer):
            if not self.buffer:
                self.closing.wait(0.005)
                continue
            self._write_some()

    def _write_some(self) -> None:
        take, write = self.buffer.popleft, self.writer.write
        for _ in range(min(len(self.buffer), 10_000)):
            key, encoding, data, t_ns = take()
            if key.startswith(REDLINE_PREFIX):
                encoding, t_ns = JSON_ENCODING, _json_time(data, t_ns)
            write(key, data, encoding=encoding, t_ns=t_ns)
            self.written += 1

    def finish(self, meta_path: Path) -> None:
        self.closing.set()
        self.thread.join()
        meta = _read_meta(meta_path)
        self.writer.metadata(META_RUN, meta.get("run", {}))
        self.writer.metadata(META_HOST, meta.get("host", {}))
        self.writer.metadata(META_RECORDER, self.counts())
        self.writer.close()


def _json_time(data: bytes, default: int) -> int:
    try:
        stamp = json.loads(data).get("t_ns")
    except (ValueError, AttributeError):
        return default
    return stamp if isinstance(stamp, int) else default


def _read_meta(path: Path) -> dict[str, Any]:
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError) as exc:
        print(f"redline-recorder: no run metadata ({exc})", file=sys.stderr, flush=True)
        return {}


def record(out: Path, meta: Path, buffer_size: int, stop: threading.Event) -> dict[str, int]:
    """Record until ``stop`` is set; returns the counts."""
    recorder = Recorder(out, buffer_size)
    recorder.thread.start()
    try:
        with open_client(client_settings_from_env()) as session:
            session.declare_subscriber("**", recorder.taps[0])
            session.declare_subscriber(REDLINE_PREFIX + "**", recorder.taps[1])

            def status(query: zenoh.Query) -> None:
                with query:
                    query.reply(STATUS_KEY, json.dumps(recorder.counts()))

            session.declare_queryable(STATUS_KEY, status)
            print("redline-recorder ready", flush=True)
            while not stop.wait(0.2):
                pass
    finally:
        recorder.finish(meta)
    return recorder.counts()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Redline's recorder")
    parser.add_argument("--out", type=Path, required=True, help="the MCAP file to write")
    parser.add_argument("--meta", type=Path, required=True, help="JSON: {'run': {}, 'host': {}}")
    parser.add_argument("--buffer", type=int, default=200_000, help="samples queued at most")
    args = parser.parse_args(argv)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    counts = record(args.out, args.meta, args.buffer, stop)
    print(f"redline-recorder finished: {json.dumps(counts)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
