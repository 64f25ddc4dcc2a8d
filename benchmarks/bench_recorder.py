"""The recorder's throughput at 1 KiB messages: does it keep up without dropping?

Starts the recorder process on an isolated network and publishes 1 KiB messages paced at a
requested rate (batches on absolute deadlines) for a few seconds, then asks the recorder for
its counts. Figures, as ratios measured in this run: messages recorded / messages sent, the
achieved publishing rate / the requested one, and the recorder's drops. Requested rates:
100,000/s (the target) and as fast as the publisher can go.

Run: .venv/bin/python benchmarks/bench_recorder.py   (prints figures; not a test)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zenoh
from redline.agent.network import RunNetwork, open_client
from redline.agent.runner import query_recorder
from redline.recording import read_recording
from redline.testing import Link

SECONDS, SIZE, BATCH = 3.0, 1024, 500


def publish(link: Link, key: str, rate: float | None) -> tuple[int, float]:
    """Messages sent and seconds taken, paced at ``rate`` (None: as fast as possible); the
    link counts them as `Publish` would, so the recording says what was lost."""
    publisher = link.publisher(key)
    payload, sent = b"r" * SIZE, 0
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < SECONDS:
        if rate is not None and sent / rate > elapsed:
            time.sleep(min(0.001, sent / rate - elapsed))
            continue
        for _ in range(BATCH):
            publisher.put(payload)
        sent += BATCH
    link.count_sent(key, sent)
    return sent, time.perf_counter() - start


def settled(session: zenoh.Session) -> dict[str, int]:
    """The recorder's counts once they stop growing (its queue has been written out)."""
    last: dict[str, int] = {}
    while True:
        time.sleep(0.5)
        now = query_recorder(session, 30.0) or {}
        if now == last:
            return now
        last = now


def main() -> None:
    folder = Path(tempfile.mkdtemp(prefix="bench-recorder-"))
    (folder / "meta.json").write_text(json.dumps({"run": {"component": "bench"}, "host": {}}))
    out = folder / "bench.mcap"
    with RunNetwork() as network:
        env = {**os.environ, "REDLINE_ZENOH": json.dumps(network.client_settings())}
        recorder = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "redline.agent.recorder",
                "--out",
                str(out),
                "--meta",
                str(folder / "meta.json"),
            ],
            env=env,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert recorder.stdout is not None
        recorder.stdout.readline()
        with open_client(network.client_settings()) as session:
            while query_recorder(session, 0.5) is None:
                time.sleep(0.1)
            before = query_recorder(session, 5.0) or {}
            link = Link(session)
            for name, rate in (("paced", 100_000.0), ("flat-out", None)):
                sent, seconds = publish(link, f"bench/{name}", rate)
                after = settled(session)
                got = after["received"] - before["received"]
                dropped = after["dropped"] - before["dropped"]
                asked = f"{rate:,.0f}/s" if rate else "max"
                print(
                    f"{name:>8} (asked {asked}): sent {sent / seconds:,.0f}/s; recorded/sent "
                    f"{(got - dropped) / sent:.4f}; dropped {dropped}; received/sent "
                    f"{got / sent:.4f}; writer lag at worst {after.get('lag_max_ms')} ms"
                )
                before = after
            link.close()  # reports the put counts to the recorder
        recorder.terminate()
        recorder.wait()
    recording = read_recording(out)
    meta = recording.metadata["redline.recorder"]
    print(
        f"file: {sum(recording.traffic.values()):,} messages; recorder metadata: lost "
        f"{meta.get('lost')} {meta.get('lost_by_key')}; dropped {meta['dropped']}; shared "
        f"memory {meta.get('zenoh_shared_memory')}"
    )
    for path in folder.iterdir():
        path.unlink()
    folder.rmdir()


if __name__ == "__main__":
    main()
