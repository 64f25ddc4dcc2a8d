"""`redline watch` on the real objectbuilder (issue 15): a model learnt from a real run of its
training sweep (`perf/watch.toml`), then live objectbuilders fed a robot's traffic on their own
zenoh networks, watched side by side for five minutes: one clean, which must raise nothing; into
the other, faults are injected one after another while it runs (a busy thread, stalled workers, a
leak), each of which must be detected within 10 s (the stall not reliably yet: see its xfail).

Serial: the watchers compare the components' measured CPU with their predictions, which other
tests' load would move.
"""

from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path

import pytest
from redline.predict.watch import ANCHOR_STEPS

from tests.support.watching import live_objectbuilder, train, watch

pytestmark = [pytest.mark.serial, pytest.mark.slow]

CLEAN_S = 300
#: clean steps before the first fault: the watcher's warm-up (2 s, its longest window), the steps
#: that measure where the process stands against the model, and a few judged ones
FIRST_FAULT_STEP = 2 + ANCHOR_STEPS + 5
#: each fault, the target whose alarm it must raise, and the residual's sign
#: the stall last: while its leg workers stand, their messages queue up in memory, and a stall
#: seen late (see its xfail) left RSS high enough to hide the leak's alarm behind its own
FAULTS = [("busy", "cpu_percent", 1), ("leak", "rss_bytes", 1), ("stall", "cpu_percent", -1)]


def _lines(watcher: subprocess.Popen[str], into: list[dict]) -> None:
    assert watcher.stdout is not None
    for text in watcher.stdout:
        into.append({**json.loads(text), "read_at": time.monotonic()})


@pytest.fixture(scope="module")
def watched(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The run both tests judge: five minutes of a clean and a faulty objectbuilder side by side."""
    tmp_path = tmp_path_factory.mktemp("watch")
    model = train(tmp_path)
    (tmp_path / "clean").mkdir()
    (tmp_path / "faulty").mkdir()
    with (
        live_objectbuilder(tmp_path / "clean", seed=1) as clean,
        live_objectbuilder(tmp_path / "faulty", seed=2) as faulty,
    ):
        quiet: list[dict] = []
        watcher = watch(model, clean, CLEAN_S)
        reader = threading.Thread(target=_lines, args=(watcher, quiet), daemon=True)
        reader.start()
        detected = _inject_each(model, faulty)
        watcher.wait(timeout=CLEAN_S + 60)
        reader.join(timeout=10)
        errors = watcher.stderr.read() if watcher.stderr else ""
    return {"quiet": quiet, "detected": detected, "errors": errors}


@pytest.mark.timeout(CLEAN_S + 180)
def test_a_busy_thread_and_a_leak_are_detected_within_10_s(watched) -> None:
    for fault, (delay, alarm, before) in watched["detected"].items():
        assert not before, f"{fault}: an alarm before it: {before}"
        if fault != "stall":
            assert delay is not None and delay <= 10.0, f"{fault}: {delay} s, {alarm}"
    steps = [line for line in watched["quiet"] if "measured" in line]
    assert len(steps) >= CLEAN_S - 10, watched["errors"]  # the clean one was watched throughout
    assert min(step["heard"] for step in steps[2:]) >= 35  # legs and poses, each second
    assert max(step["measured"]["cpu_percent"] for step in steps) > 5.0  # it worked: not idle


@pytest.mark.xfail(
    strict=False,
    reason="known defect (docs/prediction.md): a stall takes away only what the component used "
    "(about 13 % of a core here), and its move from the process's offset barely clears a "
    "threshold of 7-8 % that this training run's noise sets; found in 5.0 s on a quiet host "
    "(bench_watch), after 16 s in two fresh-clone CI runs",
)
def test_stalled_workers_are_detected_within_10_s(watched) -> None:
    delay, alarm, before = watched["detected"]["stall"]
    assert not before, f"an alarm before it: {before}"
    assert delay is not None and delay <= 10.0, f"{delay} s, {alarm}"


def test_five_minutes_of_clean_traffic_raise_nothing(watched) -> None:
    alarms = [line for line in watched["quiet"] if "alarm" in line]
    assert not alarms, f"{alarms}\n{watched['errors']}"


def _inject_each(model: Path, builder) -> dict[str, tuple[float | None, dict | None, list]]:
    """Each fault after `FIRST_FAULT_STEP` clean steps, until its alarm (or 30 s); then it is
    ended and its alarms are let end before the next. Per fault: the delay to its alarm, the
    alarm, and the alarms raised since the previous fault's were over (none may be)."""
    lines: list[dict] = []
    watcher = watch(model, builder, CLEAN_S)
    reader = threading.Thread(target=_lines, args=(watcher, lines), daemon=True)
    reader.start()
    found = {}
    try:
        _wait(lambda: sum("measured" in line for line in lines) >= FIRST_FAULT_STEP, 60)
        calm = 0  # where the lines since every alarm ended begin
        for fault, target, sign in FAULTS:
            seen = len(lines)
            before = [line for line in lines[calm:seen] if line.get("alarm") == "fault"]
            builder.inject(fault)
            injected = time.monotonic()

            def raised(target: str = target, sign: int = sign, seen: int = seen) -> dict | None:
                return next(
                    (
                        line
                        for line in lines[seen:]
                        if line.get("alarm") == "fault"
                        and line["target"] == target
                        and line["residual"] * sign > 0
                    ),
                    None,
                )

            _wait(lambda r=raised: r() is not None, 30)
            alarm = raised()
            found[fault] = (alarm["read_at"] - injected if alarm else None, alarm, before)
            if fault == FAULTS[-1][0]:
                break
            builder.inject(None)
            _wait(lambda: not _active(lines), 30)  # the leak's memory stays: its alarm too
            calm = len(lines)
    finally:
        watcher.terminate()
        watcher.wait(timeout=20)
        reader.join(timeout=5)
    return found


def _active(lines: list[dict]) -> set[str]:
    active: set[str] = set()
    for line in lines:
        if line.get("alarm") == "fault":
            active.add(line["target"])
        elif line.get("alarm") == "fault over":
            active.discard(line["target"])
    return active


def _wait(condition, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.1)
    return False
