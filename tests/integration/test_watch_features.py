"""The features a model is trained on (extracted from a recording) and the features `redline watch`
predicts from (heard by its live zenoh subscribers) are the same vectors for the same traffic
(issue 15): one real network, the real recorder process writing the traffic to MCAP, and the
watcher's own listener beside it, both hearing bursts a publisher sends half-way between the
time steps (so that the microseconds between two subscribers cannot move a sample across a
window's edge)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from redline.agent.network import RunNetwork, open_client
from redline.agent.recorder import query_recorder
from redline.commands.watch import listen
from redline.predict.features import NS, FeatureSpec, extract
from redline.predict.watch import EventWindow
from redline.recording import read_recording

pytestmark = pytest.mark.slow

SPEC = FeatureSpec((("robot/legs", "in"), ("robot/persons", "out"), ("robot/pose", "in")))
BURSTS = 14  # one a second: longer than the longest window (10 s)


def test_a_recording_and_a_live_watcher_give_the_same_feature_vectors(tmp_path) -> None:
    with RunNetwork() as network:
        meta = tmp_path / "meta.json"
        meta.write_text("{}")
        recorder = subprocess.Popen(
            [sys.executable, "-m", "redline.agent.recorder", "--out", str(tmp_path / "run.mcap"),
             "--meta", str(meta)],
            env={**os.environ, "REDLINE_ZENOH": json.dumps(network.client_settings())},
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert recorder.stdout is not None
        assert "redline-recorder ready" in recorder.stdout.readline()
        window = EventWindow(SPEC)
        with (
            open_client(network.client_settings()) as watcher,
            open_client(network.client_settings()) as robot,
        ):
            subscribers = listen(watcher, window)
            publishers = {key: robot.declare_publisher(key) for key, _ in SPEC.channels}
            # The recorder declares its status queryable after its subscribers, and a session's
            # query follows its own declarations to the router: an answer to each session means
            # the router holds every subscription (the runner waits for the recorder so too).
            deadline = time.monotonic() + 30
            while query_recorder(watcher, 0.5) is None or query_recorder(robot, 0.5) is None:
                assert time.monotonic() < deadline, "the recorder never answered its status query"
            start = (time.time_ns() // NS + 1) * NS  # the next whole second
            steps = []
            for burst in range(BURSTS):
                time.sleep(max(0.0, (start + burst * NS + NS // 2 - time.time_ns()) / NS))
                for count in range(1 + burst % 4):  # the rates and sizes vary burst by burst
                    publishers["robot/legs"].put(b"l" * (16 * (burst + count + 1)))
                publishers["robot/persons"].put(b"p" * (8 * burst + 1))
                if burst % 3 == 0:
                    publishers["robot/pose"].put(b"{}")
                steps.append(start + (burst + 1) * NS)
            time.sleep(max(0.0, (steps[-1] - time.time_ns()) / NS) + 0.2)
            live = np.vstack([window.features(step) for step in steps])
            for subscriber in subscribers:
                subscriber.undeclare()
        recorder.send_signal(signal.SIGTERM)
        assert recorder.wait(timeout=30) == 0
    events = read_recording(tmp_path / "run.mcap", strict=False, events=True).events or []
    traffic = [event for event in events if not event[0].startswith("@")]
    assert len(traffic) == sum(1 + b % 4 for b in range(BURSTS)) + BURSTS + 5  # all recorded
    recorded = extract(traffic, np.array(steps), SPEC)
    assert recorded[-1].any()  # the vectors hold traffic, not only zeros
    for step, (mine, theirs) in enumerate(zip(live, recorded, strict=True)):
        differ = [n for n, a, b in zip(SPEC.names(), mine, theirs, strict=True) if a != b]
        assert not differ, f"step {step}: {differ}"
