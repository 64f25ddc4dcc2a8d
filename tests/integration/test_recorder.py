"""The recorder counts what zenoh lost before it (its file format: tests/unit/test_recording.py).

The test runs the real recorder process on a real isolated zenoh network; the "driver"
there is this test, which reports more samples put than it publishes, as a driver whose
samples zenoh dropped would.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from redline.agent.network import RunNetwork, open_client
from redline.agent.recorder import query_recorder
from redline.recording import read_recording
from redline.testing import Context, Link, Loop, Publish


def _start_recorder(network: RunNetwork, folder: Path) -> subprocess.Popen[str]:
    (folder / "meta.json").write_text(json.dumps({"run": {"component": "c"}, "host": {}}))
    env = {**os.environ, "REDLINE_ZENOH": json.dumps(network.client_settings())}
    recorder = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "redline.agent.recorder",
            "--out",
            str(folder / "out.mcap"),
            "--meta",
            str(folder / "meta.json"),
        ],
        env=env,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert recorder.stdout is not None and "ready" in recorder.stdout.readline()
    return recorder


def _record(folder: Path, shared_memory: bool, sent_extra: int) -> dict[str, str]:
    """Publish 200 samples on robot/cmd through the SDK, report 200 + sent_extra as put."""
    with RunNetwork(shared_memory=shared_memory) as network:
        recorder = _start_recorder(network, folder)
        try:
            with open_client(network.client_settings()) as session:
                assert any(query_recorder(session, 0.5) is not None for _ in range(60))
                link = Link(session)
                ctx = Context({}, link=link, case="c", phase="p")
                Loop(Publish("robot/cmd", b"x" * 1024), 150).run(ctx)  # compiled: bulk count
                Loop(Publish("robot/cmd", b"x" * 1024, sequence=True), 50).run(ctx)  # one by one
                assert link.sent() == {"robot/cmd": 200}
                link.count_sent("robot/cmd", sent_extra)
                link.close()  # tells the recorder what was put
        finally:
            recorder.terminate()
            assert recorder.wait(30) == 0
    return read_recording(folder / "out.mcap").metadata["redline.recorder"]


def test_samples_the_driver_sent_but_the_recorder_never_saw_are_counted_per_key(
    tmp_path: Path,
) -> None:
    counts = _record(tmp_path, shared_memory=True, sent_extra=7)
    assert counts["lost"] == "7" and counts["checked_keys"] == "1"
    assert json.loads(counts["lost_by_key"]) == {"robot/cmd": {"sent": 207, "recorded": 200}}
    assert counts["zenoh_shared_memory"] == "on"


def test_nothing_lost_and_shared_memory_off_are_recorded(tmp_path: Path) -> None:
    counts = _record(tmp_path, shared_memory=False, sent_extra=0)
    assert counts["lost"] == "0" and json.loads(counts["lost_by_key"]) == {}
    assert counts["zenoh_shared_memory"] == "off"
    assert int(counts["written"]) == int(counts["received"]) == 200
