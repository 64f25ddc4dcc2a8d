"""How long `redline` takes before it does anything, as ratios to `python -c pass`, same run.

Four command lines, each started afresh as a user starts it: the bare interpreter (`python -c
pass`, the floor), `redline --help`, `redline run --help`, and `redline run BAD.toml --out
x.mcap`, BAD.toml being the echo example's suite with a field misspelt (the error, with its
file:line, is the whole output). Each runs REPEATS times, the four taking turns so that a busy
spell on this shared host hits all of them; figures are medians, with the middle half. Goals
(issue 9, item 14): both helps in <= 0.5 s, the suite's error in <= 1 s.

Run: .venv/bin/python benchmarks/bench_cli_startup.py   (prints figures; not a test)
"""

from __future__ import annotations

import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPEATS = 15
ECHO_SUITE = Path(__file__).resolve().parents[1] / "examples" / "echo" / "perf" / "redline.toml"
GOALS = {"redline --help": 0.5, "redline run --help": 0.5, "redline run BAD.toml": 1.0}


def command_lines(folder: Path) -> dict[str, list[str]]:
    redline = str(Path(sys.executable).with_name("redline"))
    suite = folder / "redline.toml"
    suite.write_text(ECHO_SUITE.read_text().replace("sampling_hz", "sampling_rate"))
    return {
        "python -c pass": [sys.executable, "-c", "pass"],
        "redline --help": [redline, "--help"],
        "redline run --help": [redline, "run", "--help"],
        "redline run BAD.toml": [redline, "run", str(suite), "--out", str(folder / "x.mcap")],
    }


def elapsed(argv: list[str]) -> tuple[float, str]:
    """Wall-clock seconds from start to exit, and everything the process printed."""
    began = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True)
    return time.perf_counter() - began, done.stdout + done.stderr


def _spread(values: list[float]) -> str:
    q1, median, q3 = statistics.quantiles(values, n=4)
    return f"{median:6.3f} s (middle half {q1:.3f}-{q3:.3f})"


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="redline-bench-") as folder:
        lines = command_lines(Path(folder))
        times: dict[str, list[float]] = {name: [] for name in lines}
        outputs: dict[str, str] = {}
        for _ in range(REPEATS):
            for name, argv in lines.items():
                seconds, outputs[name] = elapsed(argv)
                times[name].append(seconds)
    # the figure means nothing unless the suite's mistake was actually reported
    reported = " ".join(outputs["redline run BAD.toml"].split())
    if not re.search(r"redline\.toml:\d+: unknown field 'sampling_rate'", reported):
        raise SystemExit(f"the bad suite was not reported as expected:\n{reported}")
    floor = statistics.median(times["python -c pass"])
    print(f"{REPEATS} runs each, taking turns; median wall clock from start to exit")
    for name, values in times.items():
        goal = f"   goal <= {GOALS[name]:.1f} s" if name in GOALS else ""
        print(
            f"{name:<22}{_spread(values)}   {statistics.median(values) / floor:7.1f} x "
            f"python -c pass{goal}"
        )


if __name__ == "__main__":
    main()
