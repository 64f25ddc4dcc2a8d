#!/usr/bin/env python3
"""Bootstrap and run Redline from a fresh checkout, needing only Python 3.11 and pip.

    python3 run.py demo [ARGS]   install what is needed, then `redline demo ARGS`
    python3 run.py test          install what is needed, then the whole test suite: tests not
                                 marked `serial` on pytest-xdist workers, then the `serial` ones
                                 (they measure CPU or timing) alone
    python3 run.py test ARGS     install what is needed, then `pytest ARGS` in one process (e.g.
                                 `tests/unit`, the tests that need no service)
    python3 run.py redline ARGS  install what is needed, then any `redline` command
    python3 run.py check         install what is needed, then the house's checks: ruff (lint and
                                 format), lint-imports (the layers), mypy (types)

It makes `.venv/` with `python -m venv`, puts `uv` into it with pip, and lets uv install the
workspace (agent and server, editable) from `uv.lock`. Tests need Debian's Chromium (the
browser tests) and PgBouncer: `test` installs them with apt-get when missing and we are root.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
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
    # --inexact keeps uv itself, which pip put into this environment.
    run(
        [str(BIN / "uv"), "sync", "--locked", "--all-packages", "--inexact", "--quiet"],
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


def test(args: list[str]) -> int:
    """``pytest ARGS`` in one process; without ARGS the whole suite in its two passes."""
    pytest = [str(BIN / "python"), "-m", "pytest"]
    if args:
        return subprocess.run([*pytest, *args], cwd=ROOT).returncode
    codes = []
    for extra in PASSES:
        say(f"pytest {' '.join(extra)}")
        codes.append(subprocess.run([*pytest, *extra, *DURATIONS], cwd=ROOT).returncode)
    if any(codes):
        say(f"failed: pass exit codes {codes}")
    return next((code for code in codes if code), 0)


CHECKS = (["ruff", "check", "."], ["ruff", "format", "--check", "."], ["lint-imports"], ["mypy"])


def check() -> int:
    """Every check, each reported; non-zero when any failed."""
    failed = []
    for tool, *args in CHECKS:
        say(f"{tool} {' '.join(args)}")
        if subprocess.run([str(BIN / tool), *args], cwd=ROOT).returncode != 0:
            failed.append(tool + (f" {args[0]}" if args and tool == "ruff" else ""))
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
