"""`redline watch` on the real objectbuilder (issue 15): a model learnt from a real run of its
training sweep (`perf/watch.toml`) made on this host first, then a live
objectbuilder fed a robot's traffic on its own zenoh network and watched: for a clean minute,
which must raise nothing; then faults are injected one after another while it runs (a busy
thread, a leak, stalled workers), each of which must be detected within 10 s: the busy
thread by CPU, the leak by RSS, the stall by its silence (its persons no longer answer the legs
that keep coming: the model's CPU threshold, 20-25 % of a core on this VM, is wider than the
13 % a stall takes away). The model is learnt here, not from the committed training run: on a
VM slower than the one that recorded it, the objectbuilder used 1.5-1.8 times the CPU it
predicted, and a CI run's clean minute alarmed (docs/prediction.md). Five clean minutes are
watched as a replay of a committed run (test_watch_replay.py), in seconds: live, they took five
of the suite's twelve minutes.

Serial: the watcher compares the component's measured CPU with its prediction, which other load
moves. The faults come after the clean minutes, into the same process, never beside them: a
busy thread spinning in a neighbour objectbuilder on this 2-core VM raised the clean one's CPU
for the same traffic by 12 % of a core, beyond its threshold of 10 (a fresh-clone CI run,
2026-11-24), and a CI run's clean minute alarmed once on CPU with nothing of the suite beside it
(+17.4 against 10.66, 2026-12-06). The watcher now leaves out the CPU of a step the host was busy
in with other work, and the clean minute has a neighbour spin a core for `NEIGHBOUR_S`: those
steps must be told busy, and raise nothing.

The watcher reports its alarms to a live server, as a robot's does, with an agent token it takes
from its environment (never from its command line, which any user of the robot can read).
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest

from tests.support.api import api_with
from tests.support.servers import live_server
from tests.support.watching import live_objectbuilder, train, watch

pytestmark = [pytest.mark.serial, pytest.mark.slow]

#: the live watch's clean lead-in: warm-up, the offset's steps, and most of a minute beyond
CLEAN_S = 60
#: a neighbour process spins a core for this long from this step of the clean minute
NEIGHBOUR_S, NEIGHBOUR_AT = 8, 30
#: the longest the faults may take after the clean minutes: each one's alarm within 30 s, and the
#: busy thread's and the leak's CPU alarms over within 30 s each
FAULTS_S = 150
#: each fault, the target whose alarm it must raise, and the residual's sign
#: the stall last: while its leg workers stand, their messages queue up in memory, and RSS rose
#: enough to hide the leak's alarm behind its own
FAULTS = [
    ("busy", "cpu_percent", 1),
    ("leak", "rss_bytes", 1),
    ("stall", "silence:objectbuilder/persons", 1),
]


def _lines(watcher: subprocess.Popen[str], into: list[dict]) -> None:
    assert watcher.stdout is not None
    for text in watcher.stdout:
        into.append({**json.loads(text), "read_at": time.monotonic()})


@pytest.fixture(scope="module")
def watched(services, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The run the tests judge: an objectbuilder watched for a clean minute, then faulted, its
    alarms reported to a live server; and what the server then lists."""
    tmp_path = tmp_path_factory.mktemp("watch")
    model = train(tmp_path)
    with (
        api_with(services, tmp_path) as api,
        live_server(api.settings) as url,
        live_objectbuilder(tmp_path, seed=1) as builder,
    ):
        api.component("objectbuilder")
        token = api.tokens["agent"]["Authorization"].removeprefix("Bearer ")
        lines: list[dict] = []
        server = ("--server", url, "--component", "objectbuilder")
        watcher = watch(model, builder, CLEAN_S + FAULTS_S, server, {"REDLINE_TOKEN": token})
        reader = threading.Thread(target=_lines, args=(watcher, lines), daemon=True)
        reader.start()
        try:
            _wait(lambda: _steps(lines) >= NEIGHBOUR_AT, CLEAN_S + 60)
            spinning = _neighbour()
            _wait(lambda: _steps(lines) >= CLEAN_S, CLEAN_S + 60)
            quiet = list(lines)
            detected = _inject_each(lines, builder)
        finally:
            watcher.terminate()
            watcher.wait(timeout=20)
            reader.join(timeout=5)
        errors = watcher.stderr.read() if watcher.stderr else ""
        reported = api.client.get("/api/v1/components/objectbuilder/runtime-alerts").json()
    return {
        "quiet": quiet,
        "detected": detected,
        "errors": errors,
        "neighbour": spinning,
        "reported": reported,
        "token": token,
    }


@pytest.mark.timeout(CLEAN_S + FAULTS_S + 180)
def test_a_busy_thread_and_a_leak_are_detected_within_10_s(watched) -> None:
    for fault, (delay, alarm, before) in watched["detected"].items():
        assert not before, f"{fault}: an alarm before it: {before}"
        if fault != "stall":
            assert delay is not None and delay <= 10.0, f"{fault}: {delay} s, {alarm}"
    steps = [line for line in watched["quiet"] if "measured" in line]
    assert len(steps) >= CLEAN_S - 10, watched["errors"]  # the clean one was watched throughout
    assert min(step["heard"] for step in steps[2:]) >= 35  # legs and poses, each second
    assert max(step["measured"]["cpu_percent"] for step in steps) > 5.0  # it worked: not idle


def test_stalled_workers_are_detected_within_10_s(watched) -> None:
    delay, alarm, before = watched["detected"]["stall"]
    assert not before, f"an alarm before it: {before}"
    assert delay is not None and delay <= 10.0, f"{delay} s, {alarm}"


def test_a_clean_minute_of_live_traffic_raises_nothing(watched) -> None:
    steps = [line for line in watched["quiet"] if "measured" in line]
    alarms = [line for line in watched["quiet"] if "alarm" in line]
    # what else used the host at each step (% of a core), to tell a neighbour's burst
    others = [(s["other_cpu_percent"], s["host_busy"]) for s in steps]
    assert not alarms, f"{alarms}\nother load by step: {others}\n{watched['errors']}"


def test_a_neighbour_spinning_a_core_is_told_and_leaves_the_cpu_unjudged(watched) -> None:
    began, ended = watched["neighbour"]
    steps = [line for line in watched["quiet"] if "measured" in line]
    during = [s for s in steps if began + 1.5 <= s["t"] <= ended - 0.5]
    assert len(during) >= NEIGHBOUR_S - 3
    assert all(s["host_busy"] for s in during), [s["other_cpu_percent"] for s in during]
    assert min(s["other_cpu_percent"] for s in during) > 60  # most of a core
    told = [
        (line["host"], line["other_cpu_percent"]) for line in watched["quiet"] if "host" in line
    ]
    assert "busy" in [said for said, _ in told], told


def test_the_server_lists_each_alarm_reported_with_the_token_from_the_environment(watched):
    began = {alert["target"] for alert in watched["reported"] if alert["started"]}
    for fault, (_, alarm, _) in watched["detected"].items():
        assert alarm["target"] in began, f"{fault}: {alarm} not in {watched['reported']}"
    # the busy thread's CPU alarm ended before the leak: its end is reported too
    assert any(not a["started"] and a["target"] == "cpu_percent" for a in watched["reported"])
    assert "could not report" not in watched["errors"], watched["errors"]
    assert watched["token"] not in watched["errors"]


def _inject_each(lines: list[dict], builder) -> dict[str, tuple[float | None, dict | None, list]]:
    """Each fault into the watched objectbuilder, until its alarm (or 30 s); then it is ended and
    its CPU alarm is let end before the next (a leak's memory stays, and its alarm with it). Per
    fault: the delay to its alarm, the alarm, and the alarms raised since the previous fault's
    were over, the clean minute for the first (none may be)."""
    found = {}
    calm = 0  # where the lines since every CPU alarm ended begin
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
        _wait(lambda: "cpu_percent" not in _active(lines), 30)
        calm = len(lines)
    return found


def _neighbour() -> tuple[float, float]:
    """A process spinning a core for `NEIGHBOUR_S` beside the watched one; when it ran, in the
    watcher's clock (the time of the step before and after it)."""
    began = time.time()  # the watcher's steps are stamped with the wall clock
    spin = (
        f"import time\nend = time.monotonic() + {NEIGHBOUR_S}\nwhile time.monotonic() < end: pass"
    )
    subprocess.run([sys.executable, "-c", spin], check=True, timeout=NEIGHBOUR_S + 30)
    return began, time.time()


def _steps(lines: list[dict]) -> int:
    return sum("measured" in line for line in lines)


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
