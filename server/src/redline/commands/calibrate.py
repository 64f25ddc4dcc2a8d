"""`redline calibrate`: run a suite several times on the same code and say, per series, how much it
moves between executions and what changes Redline can therefore see (`redline.detect.calibration`).

Everything beyond typer is imported when the command runs: every `redline` command line imports
this module to build the CLI.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    from redline.detect.calibration import Calibrated
    from redline.recording import SeriesKey


def _execution_values(
    recordings: list[Path], limit: float
) -> tuple[dict[SeriesKey, list[float]], dict[SeriesKey, int]]:
    """Per judged series, one value per recording (the median of its samples), and in how
    many recordings its segment was disturbed (the host busy). A disturbed segment's value is
    left out, as the service does not judge it: the spread is the quiet host's."""
    import numpy as np
    from redline.detect.counters import is_count, judged_among
    from redline.recording import read_recording
    from redline.recording.disturbance import recording_disturbances

    values: dict[SeriesKey, list[float]] = {}
    busy: dict[SeriesKey, int] = {}
    for path in recordings:
        samples = read_recording(path).series_samples()
        disturbed = recording_disturbances(samples, limit)
        asked = set(judged_among(samples))
        for key, series in samples.items():
            if not series or key not in asked or is_count(key.process, key.counter):
                continue
            if (key.case, key.phase, key.params) in disturbed:
                busy[key] = busy.get(key, 0) + 1
                continue
            values.setdefault(key, []).append(float(np.median(series)))
    return values, busy


def _row(found: Calibrated, busy: int) -> dict[str, Any]:
    return {
        "series": found.key.label(),
        "executions": found.executions,
        "median": found.median,
        "cv": found.cv,
        "spread": found.spread,
        "detectable": found.detectable,
        "executions_for_target": found.needed,
        "disturbed": busy,
    }


def _pct(value: float) -> str:
    return f"{100 * value:.1f} %" if value != float("inf") else "inf"


def calibrate_cmd(
    suite: Annotated[
        Path, typer.Argument(help="the suite file (redline.toml)", exists=True, dir_okay=False)
    ],
    executions: Annotated[
        int,
        typer.Option("--executions", "-n", min=2, help="executions of the same code to measure"),
    ] = 5,
    target: Annotated[
        float, typer.Option(help="the relative change to size the executions for (0.05: 5 %)")
    ] = 0.05,
    per_revision: Annotated[
        int | None,
        typer.Option(min=1, help="executions per revision to size for (default: the suite's)"),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(file_okay=False, help="folder for the recordings (default: a temporary one)"),
    ] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", dir_okay=False, help="also write the figures as JSON")
    ] = None,
    only: Annotated[
        list[str] | None, typer.Option("--only", help="run only this test case (repeatable)")
    ] = None,
) -> None:
    """Run SUITE N times and report per series the spread between executions (CV), the
    smallest change detectable at the default settings, and the executions needed for TARGET.
    """
    from redline.agent.processes import RunError
    from redline.agent.runner import run_executions
    from redline.agent.suite import SuiteError, load_suite
    from redline.detect.calibration import calibrate
    from redline.recording.disturbance import threshold
    from redline.testing import ValidationError

    try:
        per = per_revision or load_suite(suite).executions
        folder = out or Path(tempfile.mkdtemp(prefix="redline-calibrate-"))
        results = run_executions(
            suite,
            folder / "calibrate.mcap",
            executions=executions,
            progress=lambda m: typer.echo(m, err=True),
            only=only or (),
        )
    except (SuiteError, ValidationError, RunError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    values, busy = _execution_values([r.recording for r in results], threshold())
    rows = [_row(found, busy.get(found.key, 0)) for found in calibrate(values, per, target)]
    typer.echo(f"{'series':<70} {'cv':>8} {'spread':>8} {'detect':>8} {'n for':>6} busy")
    for row in rows:
        needed = row["executions_for_target"]
        typer.echo(
            f"{row['series'][:70]:<70} {_pct(row['cv']):>8} {_pct(row['spread']):>8} "
            f"{_pct(row['detectable']):>8} {needed if needed else '-':>6} "
            f"{row['disturbed'] or ''}"
        )
    typer.echo(
        f"{executions} executions; detectable: the smallest change flagged with {per} "
        f"execution(s) per revision; n for: executions per revision for a "
        f"{100 * target:g} % change ('-': out of reach at the defaults); busy: "
        f"executions whose phase the host was busy in, left out. Recordings: {folder}"
    )
    unmeasured = sorted(key.label() for key in busy.keys() - values.keys())
    if unmeasured:
        typer.echo(
            f"warning: {len(unmeasured)} series had the host busy in every execution and are "
            f"left out (first: {unmeasured[0]}); run again on a quiet host",
            err=True,
        )
    if json_out is not None:
        json_out.write_text(
            json.dumps(
                {"executions": executions, "per_revision": per, "target": target, "series": rows},
                indent=1,
            )
        )


def register(app: typer.Typer) -> None:
    app.command("calibrate")(calibrate_cmd)
