"""`redline watch` on the real objectbuilder (issue 15): a model learnt from a real run of its
training sweep (`perf/watch.toml`), then the live component fed a robot's traffic on its own zenoh
network, with faults injected into it while it runs (a busy thread, a leak, stalled workers):
each is detected within 10 s, and minutes of clean traffic raise nothing.

Serial: the watcher compares the component's measured CPU with its prediction, which other
tests' load would move.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from tests.support.watching import LiveBuilder, live_objectbuilder, train, watch

pytestmark = [pytest.mark.serial, pytest.mark.slow]

#: clean steps before a fault is injected
CLEAN_STEPS = 15


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return train(tmp_path_factory.mktemp("watch-model"))


def watched(
    model: Path,
    builder: LiveBuilder,
    seconds: float,
    fault: str | None = None,
    target: str | None = None,
) -> tuple[list[dict], float | None, str]:
    """Watch for ``seconds`` (and inject ``fault`` after `CLEAN_STEPS` steps); the lines, when
    the fault was injected (monotonic time), and the watcher's stderr. Stops at the first alarm
    on ``target`` after the injection."""
    watcher = watch(model, builder, seconds)
    assert watcher.stdout is not None
    lines: list[dict] = []
    injected = None
    try:
        for text in watcher.stdout:
            line = json.loads(text)
            line["read_at"] = time.monotonic()
            lines.append(line)
            steps = sum(1 for item in lines if "measured" in item)
            if fault and injected is None and steps == CLEAN_STEPS:
                builder.inject(fault)
                injected = time.monotonic()
            if injected is not None and line.get("alarm") == "fault" and line["target"] == target:
                break
    finally:
        watcher.terminate()
        _, errors = watcher.communicate(timeout=20)
    return lines, injected, errors


@pytest.mark.timeout(480)
def test_five_minutes_of_clean_traffic_raise_nothing(model: Path, tmp_path: Path) -> None:
    with live_objectbuilder(tmp_path) as builder:
        lines, _, errors = watched(model, builder, 300)
    alarms = [line for line in lines if "alarm" in line]
    steps = [line for line in lines if "measured" in line]
    assert not alarms, f"{alarms}\n{errors}"
    assert len(steps) >= 290, errors  # it watched the whole time
    assert min(step["heard"] for step in steps[2:]) >= 60  # legs, poses and persons, each second
    cpu = [step["measured"]["cpu_percent"] for step in steps]
    assert max(cpu) > 5.0  # the component did work: a quiet run of an idle one proves nothing


@pytest.mark.parametrize(
    ("fault", "target", "sign"),
    [("busy", "cpu_percent", 1), ("stall", "cpu_percent", -1), ("leak", "rss_bytes", 1)],
)
def test_a_fault_injected_into_the_running_component_is_detected_within_10_s(
    model: Path, tmp_path: Path, fault: str, target: str, sign: int
) -> None:
    with live_objectbuilder(tmp_path) as builder:
        lines, injected, errors = watched(model, builder, CLEAN_STEPS + 40, fault, target)
    assert injected is not None, errors
    before = [line for line in lines if "alarm" in line and line["read_at"] < injected]
    assert not before, f"an alarm before the fault: {before}\n{errors}"
    alarm = lines[-1]  # a stall may raise the RSS (its messages queue up) before the CPU falls
    assert alarm.get("alarm") == "fault", f"not detected: {lines[CLEAN_STEPS:]}\n{errors}"
    assert alarm["target"] == target and alarm["residual"] * sign > alarm["threshold"]
    assert alarm["read_at"] - injected <= 10.0
