"""The one `redline` command: agent commands always, the server's when redline-server is there."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

import pytest
import typer
from redline.cli import main as cli
from typer.core import TyperCommand, TyperGroup
from typer.testing import CliRunner

from tests.support import ROOT

AGENT_ONLY = """
import importlib.metadata as md, sys
real = md.distribution
def distribution(name):
    if name == "redline-server":
        raise md.PackageNotFoundError(name)
    return real(name)
md.distribution = distribution
for blocked in ("redline.server", "redline.detect", "redline.worker", "scipy", "fastapi"):
    sys.modules[blocked] = None  # as if only redline-agent were installed
from redline.cli.main import main
sys.argv = ["redline", "--help"]
main()
"""


def test_without_the_server_distribution_only_agent_commands_are_offered():
    done = subprocess.run([sys.executable, "-c", AGENT_ONLY], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert " run " in done.stdout and " agent " in done.stdout
    assert " server " not in done.stdout and " compare " not in done.stdout


def test_with_the_server_distribution_every_command_is_offered(monkeypatch: pytest.MonkeyPatch):
    assert cli.server_installed()
    assert set(cli._SERVER_COMMANDS) <= set(cli.command_modules())
    monkeypatch.setattr(metadata, "distribution", _missing)
    assert cli.command_modules() == cli._AGENT_COMMANDS


def _missing(name: str) -> None:
    raise metadata.PackageNotFoundError(name)


# Libraries that only some commands' bodies need; building the CLI must not load them.
HEAVY = (
    "scipy",
    "pandas",
    "numpy",
    "sqlalchemy",
    "fastapi",
    "celery",
    "plotly",
    "pyarrow",
    "pydantic_settings",
    "sklearn",
)
LOADED = """
import sys
from redline.cli.main import main
sys.argv = ["redline", *sys.argv[1:]]
code = 0
try:
    main()
except SystemExit as exc:
    code = exc.code
print("loaded:", *sorted({name.partition(".")[0] for name in sys.modules}), file=sys.stderr)
sys.exit(code)
"""
ECHO_SUITE = ROOT / "examples" / "echo" / "perf" / "redline.toml"


def _loaded(*args: str) -> tuple[list[str], subprocess.CompletedProcess[str]]:
    """Run `redline ARGS` in a fresh interpreter; which of HEAVY and zenoh it had imported."""
    done = subprocess.run(
        [sys.executable, "-c", LOADED, *args],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "1000"},  # a long path in a message stays on one line
    )
    marker = [line for line in done.stderr.splitlines() if line.startswith("loaded:")]
    assert marker, done.stderr
    loaded = set(marker[-1].split()[1:])
    return sorted(loaded & {*HEAVY, "zenoh"}), done


@pytest.mark.parametrize("args", [["--help"], ["run", "--help"], ["compare", "--help"]])
def test_help_loads_none_of_the_service_libraries(args: list[str]) -> None:
    loaded, done = _loaded(*args)
    assert "Usage" in done.stdout
    assert loaded == [], f"`redline {' '.join(args)}` imported {loaded}"


def test_a_bad_suite_is_reported_with_its_line_before_any_service_library_loads(
    tmp_path: Path,
) -> None:
    suite = tmp_path / "redline.toml"  # the echo example's, with a misspelt field
    suite.write_text(ECHO_SUITE.read_text().replace("sampling_hz", "sampling_rate"))
    loaded, done = _loaded("run", str(suite), "--out", str(tmp_path / "x.mcap"))
    error = " ".join(done.stderr.split())
    assert re.search(rf"{re.escape(str(suite))}:\d+: unknown field 'sampling_rate'", error), error
    assert done.returncode == 2, done.returncode  # bad input, as compare and ci wait say it
    assert set(loaded) <= {"zenoh"}, f"a bad suite file imported {loaded}"


def test_a_test_module_that_cannot_be_imported_is_bad_input_before_anything_runs(
    tmp_path: Path,
) -> None:
    """A trial's test module with a syntax error exited 1, "an error during the run", where
    `--help` and writing-tests.md say 2: the suite's tests cannot be used, nothing ran."""
    shutil.copytree(ECHO_SUITE.parents[1], tmp_path / "echo")
    tests = tmp_path / "echo" / "perf" / "test_echo.py"
    tests.write_text(tests.read_text() + "\nQ = Query((\n")
    suite = tmp_path / "echo" / "perf" / "redline.toml"
    _, done = _loaded("run", str(suite), "--out", str(tmp_path / "x.mcap"))
    error = " ".join(done.stderr.split())
    assert "test_echo.py" in error and "cannot import test module: " in error, error
    assert "SyntaxError" in error and done.returncode == 2, (done.returncode, error)
    assert not (tmp_path / "x.mcap").exists()  # nothing ran


Command = TyperCommand | TyperGroup


def _commands(
    command: Command, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], Command]]:
    """Every command of the tree under ``command``, with the words that reach it."""
    if isinstance(command, TyperGroup):
        for name, sub in command.commands.items():
            yield from _commands(sub, (*path, name))
    else:
        yield path, command


def test_every_command_declares_its_options_and_its_help_lists_each() -> None:
    cli._register_all()
    commands = list(_commands(typer.main.get_command(cli.app)))
    assert {path[0] for path, _ in commands} >= {"run", "agent", "compare", "evaluate", "up"}
    for path, command in commands:
        # An option Click does not know of can be neither listed nor named when it is missing.
        assert not command.context_settings.get("ignore_unknown_options"), path
        shown = CliRunner().invoke(cli.app, [*path, "--help"], env={"COLUMNS": "200"})
        assert shown.exit_code == 0, (path, shown.output)
        for param in command.params:
            option = param.param_type_name == "option"
            names = [*param.opts, *param.secondary_opts] if option else [param.name]
            for name in names:
                assert name in shown.output, f"`redline {' '.join(path)} --help` omits {name}"


def test_a_run_stopped_before_anything_was_recorded_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import signal
    import time

    from redline.cli import run_cmd

    with pytest.raises(typer.Exit) as stopped:
        run_cmd._stopped_by(signal.SIGTERM, tmp_path / "run.mcap", time.time())
    assert stopped.value.exit_code == 143
    said = " ".join(capsys.readouterr().err.split())
    assert "terminated by SIGTERM" in said and "before anything was recorded" in said


def test_ci_waits_undecided_exit_names_each_cases_own_reason():
    """A trial's verdict, undecided because a measurement went missing, was said to be a busy
    host or a failed method."""
    from redline.cli.ci_cmd import _undecided_message

    missing = (
        "not enough data for 1 of its 1 series: benchmark execution_time: not measured in this "
        "revision, though the revision before measured it"
    )
    verdict = {
        "undecided": 1,
        "cases": [
            {
                "case": "t",
                "phase": "lnt",
                "parameters": "{}",
                "state": "undecided",
                "reason": missing,
            },
            {"case": "u", "phase": "main", "parameters": "{}", "state": "passed", "reason": ""},
        ],
    }
    said = _undecided_message(verdict)
    assert said == f"1 test case(s) undecided: t / lnt {{}}: {missing}; see the page"
    many = {"undecided": 5, "cases": [dict(verdict["cases"][0], reason="x" * 400)] * 5}
    long = _undecided_message(many)
    assert (
        long.count("x" * 280) == 3 and "…" in long and long.endswith("; and 2 more; see the page")
    )


def test_a_run_written_to_a_log_keeps_every_name_whole(monkeypatch: pytest.MonkeyPatch):
    """Piped into a CI log, rich took 80 columns and cut a trial's action names to
    "FixedRate/Query(odom/la…"."""
    from redline.cli import run_cmd
    from rich.table import Table

    monkeypatch.delenv("COLUMNS", raising=False)
    monkeypatch.setattr("sys.stderr.isatty", lambda: False)
    run_cmd._console.cache_clear()
    try:
        console = run_cmd._console()
        name = "legs_and_rate/steady Sequence/FixedRate/Query(odom/latest_estimate)/Receive"
        table = Table("segment", "action", "measured")
        table.add_row(name, name, "rtt p50 412 us, 0 timeouts of 400 queries, rate achieved 40.0/s")
        with console.capture() as captured:
            console.print(table)
        assert captured.get().count(name) == 2, captured.get()
    finally:
        run_cmd._console.cache_clear()


def test_ci_waits_table_says_a_change_may_be_an_earlier_revisions() -> None:
    """The console says what the JUnit file says: a change for the worse whose range holds a
    revision that did not measure it (the host busy in its runs) may be that revision's."""
    from redline.cli.ci_cmd import _marks

    change = {"worse": True, "confirmation": "held", "between": "r24 (the host was busy ...)"}
    assert _marks(change) == " (may be an earlier revision's: r24 (the host was busy ...))"
    assert _marks({"worse": True, "confirmation": "held"}) == ""


def test_ci_waits_table_says_why_a_case_is_skipped_before_its_changes() -> None:
    """A trial's skipped case showed "trialecho ctx_voluntary_per_s -7.7 % (better)" where the
    reason it has no verdict belongs (the JUnit file said it)."""
    from redline.cli.ci_cmd import _table

    change = {"process": "echo", "counter": "ctx", "effect": -0.077, "worse": False,
              "confirmation": "", "method": "execution_shift"}  # fmt: skip
    why = "not enough data: the baseline has 3, needs 6"
    case = {"case": "echo", "phase": "steady", "parameters": {}, "state": "skipped",
            "changes": [change], "reason": why}  # fmt: skip
    verdict = {"component": "c", "revision": "r5", "cases": [case], "regressions": 0,
               "improvements": 1, "skipped": 1, "undecided": 0}  # fmt: skip
    row = next(line for line in _table(verdict, "regression").splitlines() if "skipped" in line)
    assert row.split("skipped", 1)[1].strip() == f"{why}; also: echo ctx -7.7 % (better)", row


def test_ci_wait_names_three_open_regressions_before_a_revision_and_counts_the_rest():
    """The regressions still open before a revision: up to three named, with their pages, and
    how many more, with where to see them (the verdict's ``open_before``)."""
    from redline.cli.ci_cmd import _open_before

    found = [
        {
            "id": number,
            "confirmation": "confirmed",
            "state": "new",
            "good_revision": f"r{number - 1}",
            "bad_revision": f"r{number}",
            "largest": f"case/steady: svc cpu_percent +{number}0 % at r{number}",
            "page": f"/regressions/{number}",
        }
        for number in (9, 7, 5)
    ]
    verdict = {"component": "my svc", "open_before": found, "open_before_total": 5}
    lines = _open_before(verdict, "http://h:8080").splitlines()
    assert lines[0].startswith("5 regression(s) still open before this revision")
    assert lines[1] == (
        "  #9 confirmed, triage new: after r8, shows at r9: case/steady: svc cpu_percent +90 % "
        "at r9  http://h:8080/regressions/9"
    )
    assert lines[-1] == (
        "  and 2 more, among the component's: http://h:8080/regressions?component=my%20svc"
    )
    assert len(lines) == 5
