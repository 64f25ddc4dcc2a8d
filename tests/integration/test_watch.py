"""`redline watch` as a real command against a real process on a real (isolated) zenoh network: a
model of a leg-processing component learnt from recordings, then a stand-in component whose
traffic matches what the model expects, idle, until a busy thread is injected into it (a fault
the model cannot explain by its communication): no alarm before, an alarm within 10 s after.

Serial: the model is learnt from synthetic recordings whose samples keep perfect time, so it
knows nothing of a driver thread that a loaded host delays and then bursts; in the parallel pass
of two fresh-clone CI runs (2026-11-24) such bursts moved its CPU prediction from 0.2 to 4-8 %
of a core for a stand-in at 0.2 %, and the watcher alarmed on usage the model could not explain
before the fault was injected. (Holding each feature within its training range did not prevent
it, tried offline; a model learnt from a real run, as `test_watch_objectbuilder`'s, has seen
its driver's jitter.)"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
from redline.agent.network import RunNetwork, open_client
from redline.predict.dataset import dataset, read_run
from redline.predict.model import ModelFile
from redline.predict.watch import ANCHOR_STEPS

from tests.support.api import api_with
from tests.support.predict import SMALL, record
from tests.support.servers import live_server

REDLINE = str(Path(sys.executable).parent / "redline")
COMPONENT = textwrap.dedent(
    """
    import os, sys, time
    flag = sys.argv[1]
    while True:
        if os.path.exists(flag):
            end = time.monotonic() + 0.05
            while time.monotonic() < end:
                pass
        else:
            time.sleep(0.05)
    """
)


@pytest.mark.slow
@pytest.mark.serial  # see the module docstring
def test_watch_is_quiet_while_usage_matches_and_alarms_within_10_s_of_a_busy_thread(
    services, tmp_path
):
    runs = [
        read_run(record(tmp_path / f"t{i}.mcap", [1, 3, 5, 7], seed=i, base=0.0)) for i in (1, 2)
    ]
    model = tmp_path / "model.joblib"
    ModelFile.fit(dataset(runs), SMALL).save(model)
    flag = tmp_path / "busy"
    script = tmp_path / "component.py"
    script.write_text(COMPONENT)
    component = subprocess.Popen([sys.executable, str(script), str(flag)])
    stop = threading.Event()
    with (
        api_with(services, tmp_path) as api,
        live_server(api.settings) as url,
        RunNetwork() as network,
    ):
        api.component()
        config = network.write_component_config(tmp_path / "zenoh.json")

        def drive() -> None:  # one leg at 30 Hz: the model expects under 1 % of a core
            with open_client(network.client_settings()) as session:
                legs = session.declare_publisher("robot/legs")
                persons = session.declare_publisher("robot/persons")  # what it answers, at 10 Hz
                sent = 0
                while not stop.wait(1 / 30):
                    legs.put(b"x" * 16)
                    if sent % 3 == 0:
                        persons.put(b"p" * 8)
                    sent += 1

        driver = threading.Thread(target=drive, daemon=True)
        driver.start()
        agent = api.tokens["agent"]["Authorization"].removeprefix("Bearer ")
        watcher = subprocess.Popen(
            [REDLINE, "watch", "--model", str(model), "--process", str(component.pid),
             "--zenoh-config", str(config), "--duration", "45", "--json",
             "--server", url, "--component", "builder"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env={**os.environ, "REDLINE_TOKEN": agent},
        )  # fmt: skip
        lines: list[dict] = []
        injected = detected = None
        line: dict = {}
        try:
            for text in watcher.stdout:
                line = json.loads(text)
                lines.append(line)
                steps = sum(1 for item in lines if "measured" in item)
                # after the warm-up (10 s: its longest window) and the steps that measure where
                # this process stands against the model (`ANCHOR_STEPS`)
                if steps == 10 + ANCHOR_STEPS + 2 and injected is None:
                    flag.touch()  # the fault: a busy thread the communication does not explain
                    injected = time.monotonic()
                if line.get("alarm") == "fault" and line["target"] == "cpu_percent":
                    detected = time.monotonic() - injected if injected else None
                    break
        finally:
            stop.set()
            watcher.terminate()
            _, errors = watcher.communicate(timeout=20)
            component.kill()
            component.wait()
        reported = api.client.get("/api/v1/components/builder/runtime-alerts").json()
    alarmed = lines.index(line) if line in lines else len(lines)
    before = [item for item in lines[:alarmed] if item.get("target") == "cpu_percent"]
    assert not before, f"an alarm before the fault: {before}\n{errors}"
    assert injected is not None, f"{lines}\n{errors}"
    assert detected is not None and detected <= 10.0, (detected, errors)
    steps = [item for item in lines if "predicted" in item and not item["warming"]]
    assert min(item["heard"] for item in steps[2:]) >= 20  # the legs, at 30 Hz
    # one leg: the model expects little CPU (the median step: a late burst of the driver, on a
    # busy test host, can make one step's window hold more than its share)
    assert statistics.median(item["predicted"]["cpu_percent"] for item in steps) < 5.0
    # and the server has it (its token from the environment, never the command line)
    assert any(a["target"] == "cpu_percent" and a["started"] for a in reported), reported
