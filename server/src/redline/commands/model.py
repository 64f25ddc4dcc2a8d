"""`redline model`: resource-usage models from recordings, offline (Wienke & Wrede, Section 6).

    redline model fit RECORDING... --out MODEL [--process NAME]
    redline model score MODEL RECORDING... [--json]

``fit`` learns, per target (CPU %, RSS), how the component's process uses resources from its
communication, with a grid search over grouped cross-validation folds, and writes the model file
(`redline.predict.model.ModelFile`). ``score`` predicts the recordings' usage and prints per target
the RMSE, the RMSE of predicting their mean (the baseline) and the ratio. Exit status 2 on bad
input (an unreadable recording, no traffic, too little to train on, a model of another version).
scikit-learn is imported where it runs, not when the command line is built.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import typer

EXIT_BAD_INPUT = 2
model_app = typer.Typer(help="Resource-usage models learnt from recordings.", no_args_is_help=True)


def _fail(message: str) -> typer.Exit:
    typer.echo(f"redline model: {message}", err=True)
    return typer.Exit(EXIT_BAD_INPUT)


def _windows(text: str) -> tuple[float, ...]:
    try:
        found = tuple(sorted({float(word) for word in text.split(",") if word.strip()}))
    except ValueError:
        found = ()
    if not found or any(not 0 < w <= 600 for w in found):
        raise _fail(f"--windows {text!r}: seconds between 0 and 600, comma-separated (e.g. 1,2)")
    return found


@model_app.command("fit")
def fit(
    recordings: Annotated[list[Path], typer.Argument(help="recordings of performance tests")],
    out: Annotated[Path, typer.Option(help="the model file to write")],
    process: Annotated[
        str | None, typer.Option(help="the component process to model (default: the only one)")
    ] = None,
    received_only: Annotated[
        bool,
        typer.Option(
            help="features of the keys the component receives only: for `redline watch` (a "
            "model that also sees what the component sends explains a stall's lower CPU by its "
            "lower output, and misses the stall)"
        ),
    ] = False,
    windows: Annotated[
        str,
        typer.Option(
            help="feature windows in seconds, comma-separated (for `redline watch`, 1,2: longer "
            "windows learnt from steady test phases lag behind a load that falls)"
        ),
    ] = "1,2,5,10",
) -> None:
    """Learn a model of a component process's CPU % and RSS from its communication."""
    from redline.predict.dataset import DataError, dataset, read_run
    from redline.predict.model import ModelFile

    try:
        runs = [read_run(path) for path in recordings]
        data = dataset(runs, process, received_only=received_only, windows=_windows(windows))
        # said before the fit, which may fail for want of what was left out
        for why in data.left_out:
            typer.echo(f"warning: left out, disturbed by other load: {why}", err=True)
        model = ModelFile.fit(data)
        model.save(out)
    except DataError as exc:
        raise _fail(str(exc)) from None
    typer.echo(
        f"{out}: process {model.process}, {len(data.x)} time steps of "
        f"{len(recordings)} recording(s), {len(data.spec.channels)} keys"
    )
    for target, found in model.metrics.items():
        typer.echo(
            f"  {target}: cross-validated RMSE {found['cv_rmse']:.4g}"
            + (
                f" = {found['cv_ratio']:.0%} of predicting the mean"
                if found["cv_ratio"] is not None
                else " (the target is constant)"
            )
        )


@model_app.command("score")
def score(
    model: Annotated[Path, typer.Argument(help="a model file")],
    recordings: Annotated[list[Path], typer.Argument(help="recordings to predict")],
    as_json: Annotated[bool, typer.Option("--json", help="one JSON object on stdout")] = False,
) -> None:
    """Predict the recordings' resource usage and report the error per target."""
    from redline.predict.dataset import DataError, dataset, read_run
    from redline.predict.features import unseen
    from redline.predict.model import ModelFile

    try:
        loaded = ModelFile.load(model)
        runs = [read_run(path) for path in recordings]
        new = sorted(set().union(*(unseen(run.events, loaded.spec) for run in runs)))
        if new:
            typer.echo(
                f"warning: the model never saw these keys and ignores them: {', '.join(new)}",
                err=True,
            )
        data = dataset(runs, loaded.process, spec=loaded.spec)
        found = loaded.score(data)
    except DataError as exc:
        raise _fail(str(exc)) from None
    if as_json:
        clean = {
            t: {k: (None if math.isinf(v) else v) for k, v in m.items()} for t, m in found.items()
        }
        typer.echo(json.dumps(clean))
        return
    for target, errors in found.items():
        typer.echo(
            f"{target}: RMSE {errors['rmse']:.4g}, predicting the mean "
            f"{errors['baseline_rmse']:.4g} ({errors['ratio']:.0%})"
        )


def register(app: typer.Typer) -> None:
    app.add_typer(model_app, name="model")
