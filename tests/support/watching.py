"""A live objectbuilder for `redline watch`: the real component on an isolated zenoh network, fed
by a driver thread with a robot's traffic (leg counts that wander around 9, as the realistic
replay's do around 6, kept within the 1-11 legs the model was trained on; legs at 30/s, poses at
10/s), and its ``--faults`` file to inject a busy thread, a leak or a stall. Shared by
tests/integration/test_watch_objectbuilder.py and benchmarks/bench_watch.py."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from redline.agent.network import RunNetwork, open_client
from redline.agent.runner import run_suite
from redline.predict.dataset import dataset, read_run
from redline.predict.model import ModelFile

from tests.support import ROOT, stop

PERF = ROOT / "examples" / "objectbuilder" / "perf"
OBJECTBUILDER = ROOT / "examples" / "objectbuilder" / "objectbuilder.py"
REDLINE = str(Path(sys.executable).parent / "redline")
#: the largest leg count of watch.toml's training sweep
MAX_LEGS = 11
#: feature windows of a model for watching (docs/prediction.md): with windows up to 10 s, a model
#: learnt from steady sets over-predicted whenever the load fell (40 false alarms in 30 min);
#: with 1 and 2 s, none in 5 min and its largest smoothed residual a third of the threshold
WATCH_WINDOWS = (1.0, 2.0)


#: a real run of ``perf/watch.toml`` on this project's 2-core VM (a quiet host, 2026-11-24),
#: committed (0.2 MB): the watch test fits its model on it instead of recording a minute of its
#: own each time, as a model learnt on a performance host watches the component elsewhere. Made
#: again after a change to the objectbuilder, in ``examples/objectbuilder``, with
#: ``redline run perf/watch.toml -o perf/data/watch-training.mcap``
TRAINING = PERF / "data" / "watch-training.mcap"


def fit(recording: Path, folder: Path) -> Path:
    """A model of the objectbuilder fitted on a run of ``perf/watch.toml``, on what it receives
    only (what it sends would explain a stall's lower CPU), over windows of 1 and 2 s
    (`WATCH_WINDOWS`); written to ``folder``."""
    model = folder / "objectbuilder.model"
    data = dataset([read_run(recording)], received_only=True, windows=WATCH_WINDOWS)
    ModelFile.fit(data).save(model)
    return model


def train(folder: Path) -> Path:
    """`fit` on a real run of ``perf/watch.toml`` made now (about a minute)."""
    return fit(run_suite(PERF / "watch.toml", folder / "training.mcap").recording, folder)


def _realistic():
    spec = importlib.util.spec_from_file_location("realistic", PERF / "realistic.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@dataclass
class LiveBuilder:
    pid: int
    zenoh_config: Path
    faults: Path

    def inject(self, fault: str | None) -> None:
        """Start ``fault`` (busy, leak, stall), or end the one running (None)."""
        if fault is None:
            self.faults.unlink(missing_ok=True)
        else:
            self.faults.write_text(fault)


@contextmanager
def live_objectbuilder(folder: Path, seed: int = 20261124) -> Iterator[LiveBuilder]:
    realistic = _realistic()
    # the realistic replay's wandering crowd, three legs busier, within the counts the model was
    # trained on: a stall can only take away what the component uses, and the watcher judges it
    # by the move from where the process stood (its offset); two legs busier (about 10 % of a
    # core) left a stall's move at the threshold in a CI run (detected after 16 s), three
    # (about 13 %) leave it well beyond
    counts = np.clip(realistic.leg_counts(np.random.default_rng(seed), 30 * 600) + 3, 1, MAX_LEGS)
    ending = threading.Event()
    with RunNetwork() as network:
        config = network.write_component_config(folder / "zenoh.json")
        faults = folder / "fault"
        faults.unlink(missing_ok=True)  # no fault at the start
        component = subprocess.Popen(
            [sys.executable, str(OBJECTBUILDER), "--threads", "2", "--faults", str(faults)],
            env={**os.environ, "ZENOH_CONFIG": str(config)},
            stdout=subprocess.PIPE,
            text=True,
        )
        assert component.stdout is not None
        if "objectbuilder ready" not in component.stdout.readline():
            component.kill()
            raise RuntimeError("the objectbuilder did not start")

        def drive() -> None:
            with open_client(network.client_settings()) as session:
                # the robot listens to the persons it asks for: without a subscriber zenoh sends
                # them nowhere, and the component spends less CPU than it did in training (where
                # the recorder subscribed to everything) for the same traffic
                consumer = session.declare_subscriber("objectbuilder/persons", lambda _: None)
                legs = session.declare_publisher("objectbuilder/legs")
                pose = session.declare_publisher("objectbuilder/pose")
                pose_message = json.dumps({"x": 1.0, "y": 0.5, "theta": 0.1})
                began, index = time.monotonic(), 0
                while not ending.is_set():
                    count = int(counts[index % len(counts)])
                    legs.put(realistic.legs_payload(count, time.time_ns()))
                    if index % 3 == 0:
                        pose.put(pose_message)
                    index += 1
                    ending.wait(max(0.0, began + index / 30 - time.monotonic()))
                consumer.undeclare()

        driver = threading.Thread(target=drive, daemon=True)
        driver.start()
        try:
            yield LiveBuilder(component.pid, config, faults)
        finally:
            ending.set()
            driver.join(timeout=5)
            stop(component)


def watch(
    model: Path,
    builder: LiveBuilder,
    duration: float,
    args: tuple[str, ...] = (),
    env: dict[str, str] | None = None,
) -> subprocess.Popen[str]:
    """`redline watch --json` on the live objectbuilder, as a real command (``args``: more)."""
    return subprocess.Popen(
        [REDLINE, "watch", "--model", str(model), "--process", str(builder.pid),
         "--zenoh-config", str(builder.zenoh_config), "--duration", str(duration), "--json",
         *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, **(env or {})},
    )  # fmt: skip
