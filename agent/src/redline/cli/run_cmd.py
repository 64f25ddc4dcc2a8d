"""`redline run`: run a performance suite once on this machine and write its recording.

The runner and rich are imported when the command runs, not here: every `redline` command line
imports this module to build the CLI.
"""

from __future__ import annotations

import signal
import time
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn

import typer

if TYPE_CHECKING:
    from redline.agent.runner import RunResult
    from rich.console import Console


#: the exit code of a suite file or tests that cannot be used (as `compare`'s and `ci wait`'s)
BAD_INPUT = 2
#: the width written to a file or a CI log: wide enough that no table cuts a name short
LOG_WIDTH = 1000


@cache
def _console() -> Console:
    """The console the run reports to (stderr). Not a terminal (a CI log, a pipe), rich took
    80 columns and cut the action names of a trial's table ("FixedRate/Query(odom/la…"): it is
    given room for every name then, unless COLUMNS says otherwise."""
    import os
    import sys

    from rich.console import Console

    wide = None if sys.stderr.isatty() or os.environ.get("COLUMNS") else LOG_WIDTH
    return Console(stderr=True, highlight=False, width=wide)


def run(
    suite: Annotated[
        Path, typer.Argument(help="the suite file (redline.toml)", exists=True, dir_okay=False)
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="the MCAP recording to write")],
    keep: Annotated[
        bool, typer.Option("--keep", help="keep the workspace, and the logs after a good run too")
    ] = False,
    work: Annotated[
        Path | None,
        typer.Option(
            "--work",
            envvar="REDLINE_WORK_DIR",
            file_okay=False,
            help="folder for the run's workspace (default: the system's temporary folder)",
        ),
    ] = None,
    meta: Annotated[
        list[str] | None,
        typer.Option("--meta", help="KEY=VALUE added to the run metadata (repeatable)"),
    ] = None,
    only: Annotated[
        list[str] | None, typer.Option("--only", help="run only this test case (repeatable)")
    ] = None,
    param: Annotated[
        list[str] | None,
        typer.Option("--param", help="NAME=VALUE replacing a parameter in every set (repeatable)"),
    ] = None,
    executions: Annotated[
        int | None,
        typer.Option(
            "--executions",
            "-n",
            min=1,
            help=(
                "executions (default: the suite's); more than one writes OUT-1.mcap, OUT-2.mcap..."
            ),
        ),
    ] = None,
) -> None:
    """Run SUITE (every case, phase and parameter set) and record each execution.

    Every process of a run logs to OUT.logs/ beside the recording (run.mcap: run.logs/): kept
    when the run fails, and its error names the log and shows its last lines; removed after a
    good run unless --keep. The workspace (run metadata, the components' zenoh configuration)
    is made in --work and removed after every run unless --keep.

    Exit codes: 0 every test ran; 1 an error during the run (recorded as failed); 2 bad input
    (the suite file or its tests cannot be used: nothing ran), as `compare` and `ci wait` say
    it; 3 every test ran
    but the component took no part (it never joined the run's zenoh network, or no query was
    answered: recorded as no_traffic, with the reason); 130, 143, 129 stopped by SIGINT,
    SIGTERM, SIGHUP.
    """
    from redline.agent.interrupts import Terminated
    from redline.agent.processes import RunError
    from redline.agent.runner import run_executions
    from redline.agent.selection import parse_overrides
    from redline.agent.suite import SuiteError
    from redline.testing import ValidationError
    from rich.markup import escape

    console = _console()
    extra = dict(item.split("=", 1) for item in meta or [] if "=" in item)
    began, started = time.monotonic(), time.time()

    def progress(message: str) -> None:
        console.print(f"[dim]{time.monotonic() - began:6.1f}s[/dim] {escape(message)}")

    try:
        results = run_executions(
            suite,
            out,
            executions=executions,
            run_metadata=extra,
            progress=progress,
            keep_workspace=keep,
            only=only or (),
            overrides=parse_overrides(param or []),
            work_dir=work,
        )
    except (SuiteError, ValidationError, RunError) as exc:
        console.print(f"[bold red]error:[/bold red] {escape(str(exc))}")
        raise typer.Exit(1 if isinstance(exc, RunError) else BAD_INPUT) from None
    except (KeyboardInterrupt, Terminated) as exc:
        signum = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
        _stopped_by(signum, out, started)
    _report(results)


def _stopped_by(signum: int, out: Path, started: float) -> NoReturn:
    """Say how the run ended and which recordings it left (none, when stopped before the
    recorder started), then exit as the shells do: 130, 143, 129."""
    how = "interrupted" if signum == signal.SIGINT else "terminated"
    made = [
        path
        for path in (out, *out.parent.glob(f"{out.stem}-*{out.suffix}"))
        if path.exists() and path.stat().st_mtime >= started
    ]
    kept = (
        f"what was recorded so far is in {', '.join(map(str, made))}"
        if made
        else "it was stopped before anything was recorded"
    )
    _console().print(
        f"[bold red]{how} by {signal.Signals(signum).name}[/bold red]: every process "
        f"was stopped; {kept}"
    )
    raise typer.Exit(128 + signum)


def _report(results: list[RunResult]) -> None:
    """The last recording's summary, where each went, the phases the host was busy in; exit 3
    if any run saw no traffic."""
    from redline.cli.run_summary import driver_table, process_table
    from redline.recording import read_recording
    from redline.recording.disturbance import recording_disturbances, threshold
    from redline.recording.format import NO_TRAFFIC
    from rich.markup import escape

    console = _console()
    every = [read_recording(result.recording).series_samples() for result in results]
    console.print(process_table(every[-1]))
    driven = driver_table(every[-1])
    if driven is not None:
        console.print(driven)
    limit = threshold()
    for result, samples in zip(results, every, strict=True):
        console.print(f"[green]recorded[/green] {result.segments} segments to {result.recording}")
        for (case, phase, params), why in recording_disturbances(samples, limit).items():
            console.print(
                f"[bold yellow]WARNING[/bold yellow] {escape(case)}/{escape(phase)} "
                f"{escape(params)}: {escape(why)}; its measurements are charted, not "
                "judged (the threshold: REDLINE_DISTURBED_CPU_PERCENT)"
            )
    silent = [r for r in results if r.run_metadata.get("status") == NO_TRAFFIC]
    for result in silent:
        console.print(
            f"[bold red]WARNING: no traffic[/bold red] in {result.recording}: "
            f"{escape(result.run_metadata.get('warning', ''))}; its measurements say "
            "nothing of the component (recorded with status no_traffic)"
        )
    if silent:
        raise typer.Exit(3)


def register(app: typer.Typer) -> None:
    app.command("run")(run)
