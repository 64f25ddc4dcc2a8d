"""`redline run`: run a performance suite once on this machine and write its recording."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer
from redline.recording.format import params_name
from rich.console import Console
from rich.markup import escape
from rich.table import Table

console = Console(stderr=True, highlight=False)


def _summary(path: Path) -> Table:
    """Per segment and process: mean CPU, peak RSS and threads, read back from the file."""
    from redline.recording import read_recording

    rows: dict[tuple[str, str], dict[str, list[float]]] = {}
    for key, values in read_recording(path).series_samples().items():
        segment = f"{key.case}/{key.phase} [{params_name(json.loads(key.params))}]"
        rows.setdefault((segment, key.process), {})[key.counter] = values
    table = Table("segment", "process", "cpu % (mean)", "rss MiB (max)", "threads (max)")
    for (segment, process), counters in rows.items():
        cpu, rss = counters.get("cpu_percent", []), counters.get("rss_bytes", [])
        threads = counters.get("threads", [])
        table.add_row(
            escape(segment),
            process,
            f"{sum(cpu) / len(cpu):.1f}" if cpu else "-",
            f"{max(rss) / 2**20:.1f}" if rss else "-",
            f"{max(threads):.0f}" if threads else "-",
        )
    return table


def run(
    suite: Annotated[
        Path, typer.Argument(help="the suite file (redline.toml)", exists=True, dir_okay=False)
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="the MCAP recording to write")],
    keep: Annotated[bool, typer.Option("--keep", help="keep the workspace and logs")] = False,
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
            help="executions (default: the suite's); more than one writes OUT-1.mcap, OUT-2.mcap...",
        ),
    ] = None,
) -> None:
    """Run SUITE (every case, phase and parameter set) and record each execution."""
    from redline.agent.processes import RunError
    from redline.agent.runner import run_executions
    from redline.agent.selection import parse_overrides
    from redline.agent.suite import SuiteError
    from redline.testing import ValidationError

    extra = dict(item.split("=", 1) for item in meta or [] if "=" in item)
    began = time.monotonic()

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
        )
    except (SuiteError, ValidationError, RunError) as exc:
        console.print(f"[bold red]error:[/bold red] {escape(str(exc))}")
        raise typer.Exit(1) from None
    except KeyboardInterrupt:
        console.print(
            "[bold red]interrupted[/bold red]: every process was stopped; what was "
            "recorded so far is in the recording"
        )
        raise typer.Exit(130) from None
    console.print(_summary(results[-1].recording))
    for result in results:
        console.print(f"[green]recorded[/green] {result.segments} segments to {result.recording}")


def register(app: typer.Typer) -> None:
    app.command("run")(run)
