"""`redline watch` on the live objectbuilder (issue 15): its own cost, how fast it detects each
kind of fault, and its false alarms on clean traffic.

    .venv/bin/python benchmarks/bench_watch.py [--clean-minutes 30] [--repeats 3] [--json OUT]

1. Trains a model on a real run of ``examples/objectbuilder/perf/watch.toml`` (about a minute).
2. **Clean**: watches the objectbuilder fed a robot's traffic (`tests/support/watching.py`) for
   ``--clean-minutes`` with no fault: alarms per hour (goal 0), and the largest smoothed residual
   against the threshold. Meanwhile, the watcher's CPU (from /proc, after its first 20 s of start
   up) in % of one core at 1 Hz (goal <= 1 %), against a reference in the same run: a bare
   Python zenoh subscriber process on the same keys that only counts what it hears.
3. **Faults**: ``--repeats`` times each of busy, stall and leak, injected after `FAULT_AFTER`
   clean steps into a fresh objectbuilder: the delay from the injection to the alarm (goal
   <= 10 s).

Run it alone on the machine: the watcher compares measured CPU with its prediction.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from bench_monitor import cpu_seconds  # noqa: E402
from redline.predict.model import ModelFile  # noqa: E402
from redline.predict.watch import ANCHOR_STEPS, smooth  # noqa: E402

from tests.support.watching import live_objectbuilder, train, watch  # noqa: E402

WARM_S = 20.0
#: clean steps before a fault: the warm-up (2 s) and the steps measuring where the process stands
FAULT_AFTER = 2 + ANCHOR_STEPS + 3
#: the reference: what any Python watcher pays to hear the same keys
SUBSCRIBER = """\
import sys, zenoh
heard = [0]
with zenoh.open(zenoh.Config.from_file(sys.argv[1])) as session:
    subs = [session.declare_subscriber(k, lambda s: heard.__setitem__(0, heard[0] + 1))
            for k in sys.argv[2:]]
    print("ready", flush=True)
    sys.stdin.read()  # until the benchmark closes it
"""


class CpuWindow:
    """A process's CPU seconds between `start` and `stop`, as % of one core."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.began: tuple[float, float] | None = None
        self.percent: float | None = None

    def start(self) -> None:
        self.began = (time.monotonic(), cpu_seconds(self.pid))

    def stop(self) -> None:
        assert self.began is not None
        wall, cpu = time.monotonic() - self.began[0], cpu_seconds(self.pid) - self.began[1]
        self.percent = 100 * cpu / wall


def clean(model: Path, folder: Path, minutes: float) -> dict:
    loaded = ModelFile.load(model)
    keys = [key for key, _ in loaded.spec.channels]
    seconds = minutes * 60
    with live_objectbuilder(folder) as builder:
        reference = subprocess.Popen(
            [sys.executable, "-c", SUBSCRIBER, str(builder.zenoh_config), *keys],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert reference.stdout is not None and reference.stdout.readline().strip() == "ready"
        watcher = watch(model, builder, seconds)
        assert watcher.stdout is not None
        windows = [CpuWindow(watcher.pid), CpuWindow(reference.pid), CpuWindow(builder.pid)]
        timer = threading.Timer(WARM_S, lambda: [w.start() for w in windows])
        timer.start()
        lines = [json.loads(text) for text in watcher.stdout]  # until --duration ends it
        for window in windows:  # the watcher has printed its last step and is about to exit
            window.stop()
        watcher.wait(timeout=30)
        reference.communicate(timeout=10)
    steps = [line for line in lines if "measured" in line and not line["warming"]]
    alarms = [line for line in lines if line.get("alarm") == "fault"]
    offsets = {line["offset"]: line["taken_off"] for line in lines if "offset" in line}
    thresholds, largest, largest_moved = {}, {}, {}
    for target in ("cpu_percent", "rss_bytes"):
        residuals = np.array(
            [s["measured"][target] - s["predicted"][target] for s in steps], dtype=float
        )
        thresholds[target] = loaded.metrics[target]["threshold"]
        largest[target] = float(np.max(np.abs(smooth(residuals)))) if len(residuals) else None
        # what the watcher judges: the move from the process's offset, after the steps measuring it
        moved = residuals[ANCHOR_STEPS:] - offsets.get(target, 0.0)
        largest_moved[target] = float(np.max(np.abs(smooth(moved)))) if len(moved) else None
    watcher_cpu, reference_cpu, component_cpu = (w.percent for w in windows)
    return {
        "minutes": minutes,
        "steps": len(steps),
        "alarms": len(alarms),
        "alarms_per_hour": len(alarms) / (seconds / 3600),
        "alarm_lines": alarms,
        "offsets": offsets,
        "largest_smoothed_residual": largest,
        "largest_smoothed_move": largest_moved,
        "thresholds": thresholds,
        "watch_cpu_percent": watcher_cpu,
        "reference_subscriber_cpu_percent": reference_cpu,
        "component_cpu_percent": component_cpu,
        "watch_to_reference": watcher_cpu / reference_cpu if reference_cpu else None,
    }


def fault_delay(model: Path, folder: Path, fault: str) -> float | None:
    """Seconds from injecting ``fault`` after `FAULT_AFTER` clean steps to the alarm; None: not
    within the watch's minute."""
    with live_objectbuilder(folder) as builder:
        watcher = watch(model, builder, 60)
        assert watcher.stdout is not None
        steps, injected, delay = 0, None, None
        for text in watcher.stdout:
            line = json.loads(text)
            steps += "measured" in line
            if line.get("alarm") == "fault":
                if injected is None:
                    print(f"  a false alarm before {fault}: {line}", flush=True)
                else:
                    delay = time.monotonic() - injected
                    break
            if steps == FAULT_AFTER and injected is None:
                builder.inject(fault)
                injected = time.monotonic()
        watcher.terminate()
        watcher.communicate(timeout=20)
    return delay


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--clean-minutes", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-watch-") as tmp:
        folder = Path(tmp)
        started = time.monotonic()
        model = train(folder)
        print(f"model trained in {time.monotonic() - started:.0f} s", flush=True)
        delays: dict[str, list[float | None]] = {}
        for fault in ("busy", "stall", "leak"):
            delays[fault] = [fault_delay(model, folder, fault) for _ in range(args.repeats)]
            print(f"{fault}: detected after {delays[fault]} s", flush=True)
        found = clean(model, folder, args.clean_minutes)
    report = {"fault_delay_s": delays, "clean": found}
    moved, thresholds = found["largest_smoothed_move"], found["thresholds"]
    print(
        f"clean {found['minutes']:g} min: {found['alarms']} alarm(s) "
        f"({found['alarms_per_hour']:.1f}/h; goal 0); offsets {found['offsets']}; largest "
        "smoothed move from them "
        + ", ".join(f"{t} {moved[t]:.4g} (threshold {thresholds[t]:.4g})" for t in thresholds)
    )
    print(
        f"watch CPU {found['watch_cpu_percent']:.2f} % of a core at 1 Hz (goal <= 1 %); "
        f"a bare subscriber on the same keys {found['reference_subscriber_cpu_percent']:.2f} % "
        f"(ratio {found['watch_to_reference'] or float('nan'):.1f}x); the component "
        f"{found['component_cpu_percent']:.1f} %"
    )
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
