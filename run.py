#!/usr/bin/env python3
"""Bootstrap and run Redline from a fresh checkout, needing only Python 3.11 and pip.

    python3 run.py demo [ARGS]   install what is needed, then `redline demo ARGS`
    python3 run.py test          install what is needed, then the whole test suite: tests not
                                 marked `serial` on pytest-xdist workers, then the `serial` ones
                                 (they measure CPU or timing) alone; prints each pass's wall time
                                 and the total, and warns when the total is over 12 minutes
    python3 run.py test ARGS     install what is needed, then `pytest ARGS` in one process (e.g.
                                 `tests/unit`, the tests that need no service)
    python3 run.py redline ARGS  install what is needed, then any `redline` command
    python3 run.py check         install what is needed, then the house's checks: ruff (lint and
                                 format), lint-imports (the layers), mypy (types), and no file of
                                 agent/src or server/src over 400 lines

It makes `.venv/` with `python -m venv`, puts `uv` into it with pip, and lets uv install the
workspace (agent and server, editable) from `uv.lock`. Tests need Debian's Chromium (the
browser tests) and PgBouncer: `test` installs them with apt-get when missing and we are root.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / "bin"
#: Debian packages the tests need, and a file each installs
DEBIAN = {"chromium": Path("/usr/bin/chromium"), "pgbouncer": Path("/usr/sbin/pgbouncer")}


def say(message: str) -> None:
    print(f"[run.py] {message}", flush=True)


def run(cmd: list[str], **kwargs: object) -> None:
    subprocess.run(cmd, check=True, **kwargs)  # type: ignore[call-overload]


def ensure_environment() -> None:
    if sys.version_info[:2] != (3, 11):
        sys.exit(f"[run.py] Redline needs Python 3.11; this is {sys.version.split()[0]}")
    if not (BIN / "python").exists():
        say(f"creating {VENV}")
        run([sys.executable, "-m", "venv", str(VENV)])
    if not (BIN / "uv").exists():
        say("installing uv into the virtual environment")
        run([str(BIN / "python"), "-m", "pip", "install", "--quiet", "uv>=0.4"])
    say("syncing the workspace (uv sync)")
    env = dict(os.environ, UV_PROJECT_ENVIRONMENT=str(VENV), VIRTUAL_ENV=str(VENV))
    # --inexact keeps uv itself, which pip put into this environment. --compile-bytecode: uv
    # writes no .pyc by default, and where PYTHONDONTWRITEBYTECODE is set (as on the CI
    # machines) Python writes none either, so every process compiled every module it imported
    # from source: 5 s of CPU for the API server's import, 10.7 s for a worker's (2026-11-28).
    # uv compiles once, when it installs; a sync with nothing to install compiles nothing.
    run(
        [
            *[str(BIN / "uv"), "sync", "--locked", "--all-packages", "--inexact", "--quiet"],
            "--compile-bytecode",
        ],
        cwd=ROOT,
        env=env,
    )


def ensure_debian_packages() -> None:
    """What the tests take from Debian: Chromium for the browser tests, PgBouncer for the test
    of Redline behind it; installed with apt-get when missing and we are root."""
    missing = [package for package, path in DEBIAN.items() if not path.exists()]
    if not missing:
        return
    if shutil.which("apt-get") is None or os.geteuid() != 0:
        say(
            f"{', '.join(missing)} missing and cannot be installed here (needs root and "
            "apt-get); the tests that need them will fail until they are installed"
        )
        return
    say(f"installing Debian's {', '.join(missing)} for the tests")
    run(["apt-get", "update", "-qq"])
    run(
        ["apt-get", "install", "-y", "-qq", *missing],
        env=dict(os.environ, DEBIAN_FRONTEND="noninteractive"),
    )


#: xdist workers for the parallel pass; each starts its own embedded Postgres and Redis (or makes
#: its own database on configured servers), whole modules at a time so module fixtures run once.
#: Three on two cores: many tests wait on real processes (servers, agents, leases lapsing), and
#: the third worker fills those waits (measured: the pass took 3:10 instead of 3:58).
WORKERS = 3
PASSES = (
    # in the order tests/conftest.py sorts them (slow modules first), not xdist's by test count
    ["-n", str(WORKERS), "--dist", "loadfile", "--no-loadscope-reorder", "-m", "not serial"],
    ["-m", "serial"],
)
#: the slowest tests of each pass, printed: the suite must stay under 12 minutes in CI
DURATIONS = ["--durations=12", "--durations-min=5"]
#: the whole suite's budget in CI, in seconds (issue 10)
SUITE_BUDGET = 12 * 60


def minutes(seconds: float) -> str:
    """``seconds`` as m:ss.s (725.34 is "12:05.3")."""
    whole, rest = divmod(round(seconds, 1), 60)
    return f"{int(whole)}:{rest:04.1f}"


def timed(cmd: list[str]) -> tuple[int, float]:
    """``cmd``'s exit code and wall time in seconds."""
    began = time.monotonic()
    code = subprocess.run(cmd, cwd=ROOT).returncode
    return code, time.monotonic() - began


def over_budget(total: float) -> None:
    """Said loudly, not failed: the wall time follows the machine's load as much as the code, so
    a red run for it would be flaky; the figure is printed on every run for a reviewer to act."""
    line = "!" * 78
    say(line)
    say(f"WARNING: the suite took {minutes(total)}, over its {SUITE_BUDGET // 60}-minute budget:")
    say("make the slowest tests listed above faster, or give them to the parallel pass")
    say(line)


def test(args: list[str]) -> int:
    """``pytest ARGS`` in one process; without ARGS the whole suite in its two passes."""
    pytest = [str(BIN / "python"), "-m", "pytest"]
    if args:
        code, took = timed([*pytest, *args])
        say(f"pytest {' '.join(args)}: {minutes(took)} wall time")
        return code
    codes: list[int] = []
    times: list[float] = []
    for extra in PASSES:
        say(f"pytest {' '.join(extra)}")
        code, took = timed([*pytest, *extra, *DURATIONS])
        codes.append(code)
        times.append(took)
    for extra, took in zip(PASSES, times, strict=True):
        say(f"pass {' '.join(extra)}: {minutes(took)} wall time")
    total = sum(times)
    say(f"suite: {minutes(total)} wall time (budget {SUITE_BUDGET // 60}:00)")
    if total > SUITE_BUDGET:
        over_budget(total)
    if any(codes):
        say(f"failed: pass exit codes {codes}")
    return next((code for code in codes if code), 0)


CHECKS = (["ruff", "check", "."], ["ruff", "format", "--check", "."], ["lint-imports"], ["mypy"])
#: the packages' sources, whose files stay at MAX_LINES or under (issue 10: one room, one job)
SOURCES = ("agent/src", "server/src")
MAX_LINES = 400


def long_files() -> list[str]:
    """Each Python file of SOURCES over MAX_LINES lines, with its count, longest first."""
    counts = {
        path.relative_to(ROOT): len(path.read_bytes().splitlines())
        for source in SOURCES
        for path in (ROOT / source).rglob("*.py")
    }
    over = sorted((item for item in counts.items() if item[1] > MAX_LINES), key=lambda i: -i[1])
    return [f"{path}: {lines} lines" for path, lines in over]


def check() -> int:
    """Every check, each reported; non-zero when any failed."""
    failed = []
    for tool, *args in CHECKS:
        say(f"{tool} {' '.join(args)}")
        if subprocess.run([str(BIN / tool), *args], cwd=ROOT).returncode != 0:
            failed.append(tool + (f" {args[0]}" if args and tool == "ruff" else ""))
    say(f"files of {' and '.join(SOURCES)} over {MAX_LINES} lines")
    long = long_files()
    for file in long:
        say(f"  {file}: split it along a seam (one room, one job)")
    if long:
        failed.append(f"{len(long)} file(s) over {MAX_LINES} lines")
    if failed:
        say(f"failed: {', '.join(failed)}")
    return 1 if failed else 0


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in {"demo", "test", "redline", "check"}:
        print(__doc__)
        return 2
    command, rest = argv[0], argv[1:]
    ensure_environment()
    if command == "check":
        return check()
    if command == "test":
        ensure_debian_packages()
        return test(rest)
    if command == "demo":
        args = [str(BIN / "redline"), "demo", *rest]
    else:
        args = [str(BIN / "redline"), *rest]
    os.chdir(ROOT)
    os.execv(args[0], args)
    return 0  # not reached


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
