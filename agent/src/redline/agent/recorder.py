"""The recorder process: writes everything that crosses the run's zenoh network into one MCAP file.

    python -m redline.agent.recorder --out run.mcap --meta meta.json [--buffer 200000]

Client settings for zenoh come as JSON in ``REDLINE_ZENOH``. Subscribes to ``**`` and, because
``**`` does not match chunks starting with ``@``, to ``@redline/**`` as well. The traffic lands
in a bounded zenoh FIFO channel (filled without the GIL), Redline's own samples in a bounded
queue from a callback; one writer thread drains both into the file (see `Recorder` for why, and
for how what zenoh drops before the recorder is counted per key). Prints ``redline-recorder ready``
once subscribed, and answers queries on ``@redline/recorder/status`` with its counts (the runner
uses that as a barrier: a reply means the samples published before it have arrived) and on
``@redline/recorder/traffic`` with the samples recorded per key (the traffic check). On SIGTERM
or SIGINT it drains the queues, writes the run and host metadata found in the ``--meta`` JSON
file (read at that moment, so the runner can add the end time) and ``redline.recorder``: counts,
per-key losses, whether zenoh shared memory was on; attaches the output of each process the
file's ``logs`` names (``{process: log path}``: the components and fixtures); and finishes.
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
from redline.agent.interrupts import set_on_signals
from redline.agent.network import client_settings_from_env, open_client, shared_memory_enabled
from redline.recording.format import (
    JSON_ENCODING,
    LOG_KEEP_BYTES,
    META_HOST,
    META_RECORDER,
    META_RUN,
    RECORDER_SENT_KEY,
    REDLINE_PREFIX,
)
from redline.recording.writer import RecordingWriter

STATUS_KEY = "@redline/recorder/status"
#: answers with the samples recorded so far per key, Redline's own left out: ``{key: n}``
TRAFFIC_KEY = "@redline/recorder/traffic"
Item = tuple[str, str, bytes, int]
IDLE_S = 0.001  # the writer's nap when nothing is queued


class Tap:
    """The callback of the ``@redline/**`` subscriber (counters, markers, driver metrics: a few
    hundred samples/s): queue the sample or count it as dropped, never block."""

    def __init__(self, buffer: collections.deque[Item], capacity: int) -> None:
        self.buffer = buffer
        self.capacity = capacity
        self.received = 0
        self.dropped = 0

    def __call__(self, sample: zenoh.Sample) -> None:
        self.received += 1
        if len(self.buffer) >= self.capacity:
            self.dropped += 1
            return
        self.buffer.append(
            (str(sample.key_expr), JSON_ENCODING, sample.payload.to_bytes(), time.time_ns())
        )


class Recorder:
    """Owns the writer thread, the counts, and the per-key loss accounting.

    The component's traffic (``**``) is not taken in a Python callback: zenoh's receive thread
    would then need the GIL for every sample and stall behind the writer for up to the 5 ms
    switch interval, long enough for the router's DROP queue towards the recorder to overflow
    (the loss measured at 100,000 samples/s happened there, before any callback ran). Instead a
    zenoh FIFO channel of ``buffer_size`` samples fills without the GIL and the writer thread
    drains it. What zenoh drops before the recorder sees it cannot be counted here; it is found
    by comparing, per key, what the driver reports it put (a query on ``RECORDER_SENT_KEY`` at
    the end of the run) with what was recorded.
    """

    def __init__(self, out: Path, buffer_size: int) -> None:
        self.buffer_size = buffer_size
        self.own: collections.deque[Item] = collections.deque()
        self.tap = Tap(self.own, buffer_size)
        self.writer = RecordingWriter(out, library="redline-recorder")
        self.written = 0
        self.lag_max_ns = 0
        self.traffic: dict[str, int] = {}  # samples recorded per (non-@redline) key
        self.sent: dict[str, int] = {}  # samples the driver says it put, per key
        self.lock = threading.Lock()
        self._encodings: dict[str, str] = {}  # one channel per key: its first encoding
        self.closing = threading.Event()
        self.thread = threading.Thread(target=self._write_loop, name="writer", daemon=True)
        self.source: zenoh.Subscriber[zenoh.Handler[zenoh.Sample]] | None = None

    def counts(self) -> dict[str, int]:
        """Samples received, written and dropped by the recorder, and ``lag_max_ms``: how far the
        writer fell behind the router's stamps at worst (a backlog, not a loss)."""
        received = sum(self.traffic.values()) + self.tap.received
        return {
            "received": received,
            "written": self.written,
            "dropped": self.tap.dropped,
            "lag_max_ms": self.lag_max_ns // 1_000_000,
        }

    def losses(self) -> dict[str, tuple[int, int]]:
        """Per key the driver published on: (sent, recorded), where fewer were recorded."""
        found = {key: (sent, self.traffic.get(key, 0)) for key, sent in self.sent.items()}
        return {key: pair for key, pair in sorted(found.items()) if pair[1] < pair[0]}

    def _write_loop(self) -> None:
        while True:
            drained = self._drain_traffic(10_000) + self._drain_own()
            if drained == 0:
                if self.closing.is_set():
                    return
                time.sleep(IDLE_S)

    def _drain_traffic(self, most: int) -> int:
        if self.source is None:
            return 0
        take, write, traffic = self.source.try_recv, self.writer.write, self.traffic
        count = 0
        while count < most:
            try:
                sample = take()
            except zenoh.ZError:  # the session closed under us (an error path): nothing more
                self.source = None
                break
            if sample is None:
                break
            key = str(sample.key_expr)
            encoding = self._encodings.get(key)
            if encoding is None:
                encoding = self._encodings[key] = str(sample.encoding)
            arrived = arrival_ns(sample)
            if count == 0:  # how far behind the writer is, once per batch
                self.lag_max_ns = max(self.lag_max_ns, time.time_ns() - arrived)
            write(key, sample.payload.to_bytes(), encoding=encoding, t_ns=arrived)
            traffic[key] = traffic.get(key, 0) + 1
            count += 1
        self.written += count
        return count

    def _drain_own(self) -> int:
        count = 0
        while self.own:
            key, encoding, data, t_ns = self.own.popleft()
            stamp = _json(data).get("t_ns")
            self.writer.write(
                key, data, encoding=encoding, t_ns=stamp if isinstance(stamp, int) else t_ns
            )
            count += 1
        self.written += count
        return count

    def take_sent(self, query: zenoh.Query) -> None:
        """The driver's put counts per key (``{"key": n}``), added up over its reports."""
        with query:
            try:
                sent = json.loads(query.payload.to_bytes() if query.payload else b"{}")
                counts = {str(key): int(n) for key, n in dict(sent).items()}
            except (TypeError, ValueError) as exc:
                query.reply_err(f"expected {{key: count}}: {exc}")
                return
            with self.lock:
                for key, n in counts.items():
                    self.sent[key] = self.sent.get(key, 0) + n
            query.reply(RECORDER_SENT_KEY, "ok")

    def stop_writing(self) -> None:
        """Write what is queued, then end the writer thread."""
        self.closing.set()
        if self.thread.is_alive():
            self.thread.join()

    def finish(self, meta_path: Path, settings: dict[str, Any]) -> None:
        self.stop_writing()
        meta = _read_meta(meta_path)
        losses = self.losses()
        self.writer.metadata(META_RUN, meta.get("run", {}))
        self.writer.metadata(META_HOST, meta.get("host", {}))
        self.writer.metadata(
            META_RECORDER,
            {
                **self.counts(),
                "lost": sum(sent - got for sent, got in losses.values()),
                "sent": sum(self.sent.values()),
                "lost_by_key": {
                    key: {"sent": sent, "recorded": got} for key, (sent, got) in losses.items()
                },
                "checked_keys": len(self.sent),
                "zenoh_shared_memory": "on" if shared_memory_enabled(settings) else "off",
                "zenoh_endpoint": ",".join(settings.get("connect", {}).get("endpoints", [])),
            },
        )
        for process, path in dict(meta.get("logs", {})).items():
            try:
                output, cut = _tail(Path(path), LOG_KEEP_BYTES)
            except OSError as exc:
                output, cut = f"[its log could not be read: {exc}]\n".encode(), 0
            self.writer.log(str(process), output, cut)
        self.writer.close()


def query_recorder(session: zenoh.Session, timeout: float = 1.0) -> dict[str, int] | None:
    """The recorder's counts, or None when it does not answer (yet)."""
    for reply in session.get(STATUS_KEY, timeout=timeout):
        if reply.ok is not None:
            return dict(json.loads(reply.ok.payload.to_bytes()))
    return None


def recorded_traffic(session: zenoh.Session, timeout: float = 5.0) -> dict[str, int] | None:
    """The samples the recorder has recorded per key so far (Redline's own left out), or None
    when it does not answer."""
    for reply in session.get(TRAFFIC_KEY, timeout=timeout):
        if reply.ok is not None:
            return {str(k): int(n) for k, n in json.loads(reply.ok.payload.to_bytes()).items()}
    return None


def arrival_ns(sample: zenoh.Sample) -> int:
    """When the sample reached the run's router (which stamps every sample it routes), not when
    the writer got to it: the FIFO may hold a backlog. Now, for a sample without a stamp."""
    stamp = sample.timestamp
    return stamp.get_time_as_ntp64().as_nanos() if stamp is not None else time.time_ns()


def _json(data: bytes) -> dict[str, Any]:
    try:
        found = json.loads(data)
    except ValueError:
        return {}
    return found if isinstance(found, dict) else {}


def _tail(path: Path, keep: int) -> tuple[bytes, int]:
    """The last ``keep`` bytes of a file, and how many came before them."""
    with open(path, "rb") as stream:
        size = stream.seek(0, 2)
        cut = max(0, size - keep)
        stream.seek(cut)
        return stream.read(keep), cut


def _read_meta(path: Path) -> dict[str, Any]:
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError) as exc:
        print(f"redline-recorder: no run metadata ({exc})", file=sys.stderr, flush=True)
        return {}


def record(out: Path, meta: Path, buffer_size: int, stop: threading.Event) -> dict[str, int]:
    """Record until ``stop`` is set; returns the counts."""
    recorder = Recorder(out, buffer_size)
    settings = client_settings_from_env()
    recorder.thread.start()
    try:
        with open_client(settings) as session:
            recorder.source = session.declare_subscriber(
                "**", zenoh.handlers.FifoChannel(buffer_size)
            )
            session.declare_subscriber(REDLINE_PREFIX + "**", recorder.tap)

            def status(query: zenoh.Query) -> None:
                with query:
                    query.reply(STATUS_KEY, json.dumps(recorder.counts()))

            def traffic(query: zenoh.Query) -> None:
                with query:
                    query.reply(TRAFFIC_KEY, json.dumps(dict(recorder.traffic)))

            session.declare_queryable(STATUS_KEY, status)
            session.declare_queryable(TRAFFIC_KEY, traffic)
            session.declare_queryable(RECORDER_SENT_KEY, recorder.take_sent)
            print("redline-recorder ready", flush=True)
            while not stop.wait(0.2):
                pass
            recorder.stop_writing()  # drain the FIFO while its subscriber is still declared
    finally:
        recorder.finish(meta, settings)
    return recorder.counts()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Redline's recorder")
    parser.add_argument("--out", type=Path, required=True, help="the MCAP file to write")
    parser.add_argument("--meta", type=Path, required=True, help="JSON: {'run': {}, 'host': {}}")
    parser.add_argument("--buffer", type=int, default=200_000, help="samples queued at most")
    args = parser.parse_args(argv)
    stop = threading.Event()
    set_on_signals(stop, signal.SIGTERM, signal.SIGINT)
    counts = record(args.out, args.meta, args.buffer, stop)
    print(f"redline-recorder finished: {json.dumps(counts)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
