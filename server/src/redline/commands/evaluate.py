"""`redline evaluate CORPUS`: each detector's accuracy on a labelled corpus.

The detectors (scipy) and the corpus (pandas) are imported where they are used, not here: every
`redline` command line imports this module to build the CLI.
"""

from __future__ import annotations

import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from redline.detect.scores import MethodScores, Outcome

METRICS = ("roc_auc", "precision", "recall", "f1")


def _number(value: float) -> float | None:
    return None if math.isnan(value) else round(value, 4)


def as_json(
    results: dict[str, MethodScores], confirm: int = 0, points: dict[str, float] | None = None
) -> str:
    """``{"default": METHOD, "confirm": N, "methods": {METHOD: {every figure of the table}}}``:
    roc_auc, precision, recall, f1, tp, fp, fn, units, decided, false_alarms_per_100,
    recall_large and large (NaN as null); with ``--f1`` also ``"change_point_f1": {METHOD |
    "zero" | "binseg": F1}``."""
    from redline.detect.registry import DEFAULT_METHOD

    methods = {
        name: {
            key: _number(value) if isinstance(value, float) else value
            for key, value in scores.as_dict().items()
        }
        for name, scores in results.items()
    }
    out: dict = {"default": DEFAULT_METHOD, "confirm": confirm, "methods": methods}
    if points:
        out["change_point_f1"] = {name: round(value, 4) for name, value in points.items()}
    return json.dumps(out)


HEADER = (
    f"{'method':<19} {'ROC-AUC':>7} {'prec.':>6} {'recall':>6} {'F1':>6} {'TP':>5} {'FP':>5} "
    f"{'FN':>5} {'FA/100':>7} {'rec>=10%':>10} {'decided':>15}"
)
LEGEND = (
    "* default method; FA/100: false alarms per 100 unchanged builds; rec>=10%: "
    "recall of the changes of 10 % or more (how many); 'decided' = units not "
    "answered 'not enough data'"
)


def table_row(name: str, s: MethodScores) -> str:
    """One method's line of the table, every column apart from its neighbours."""
    from redline.detect.registry import DEFAULT_METHOD

    mark = " *" if name == DEFAULT_METHOD else ""
    large = f"{s.recall_large:.2f} ({s.large})" if s.large else "-"
    decided = f"{s.decided}/{s.units}"
    return (
        f"{name:<19} {s.roc_auc:>7.3f} {s.precision:>6.3f} {s.recall:>6.3f} {s.f1:>6.3f} "
        f"{s.tp:>5} {s.fp:>5} {s.fn:>5} {s.false_alarms_per_100:>7.1f} {large:>10} "
        f"{decided:>15}{mark}"
    )


def as_table(results: dict[str, MethodScores]) -> str:
    return "\n".join([HEADER, *(table_row(n, s) for n, s in results.items()), LEGEND])


def write_units(path: Path, outcomes: dict[str, list[Outcome]]) -> None:
    """Every unit's verdict per method: series, build, method, score, flagged, state (the
    verdict; with confirmation, a flagged unit's suspected / held / dropped), positive."""
    with path.open("w", newline="") as stream:
        out = csv.writer(stream)
        out.writerow(["series", "build", "method", "score", "flagged", "state", "positive"])
        for method, units in outcomes.items():
            for o in units:
                state = o.confirmation or o.verdict
                out.writerow(
                    [
                        o.series,
                        o.build,
                        method,
                        f"{o.score:.6g}",
                        int(o.flagged),
                        state,
                        int(o.positive),
                    ]
                )


def evaluate_cmd(
    corpus: Annotated[
        str,
        typer.Argument(
            help='corpus directory, or "sap" for the SAP HANA set (env REDLINE_SAP_CORPUS)'
        ),
    ],
    json_output: Annotated[bool, typer.Option("--json", help="print JSON only")] = False,
    methods: Annotated[
        str | None, typer.Option("--methods", help="comma-separated methods (default: all)")
    ] = None,
    executions: Annotated[
        int | None,
        typer.Option("--executions", min=1, help="use only each build's first N executions"),
    ] = None,
    confirm: Annotated[
        int,
        typer.Option(
            "--confirm",
            min=0,
            max=10,
            help="later builds a flagged change must hold over to count as flagged, as the "
            "service confirms by history (0: every flagged unit counts)",
        ),
    ] = 0,
    f1: Annotated[
        bool,
        typer.Option(
            "--f1",
            help="also score the flagged builds as change points: TCPDBench's F1 (margin 5), "
            "beside a detector that never alarms and binary segmentation",
        ),
    ] = False,
    units: Annotated[
        Path | None,
        typer.Option(
            "--units",
            dir_okay=False,
            help="also write every unit's verdict per method to this CSV file (series, build, "
            "method, score, flagged, state, positive)",
        ),
    ] = None,
) -> None:
    """ROC-AUC, precision, recall and F1 of every detection method on a labelled corpus.

    Each method's line is printed as soon as it is done; progress goes to stderr meanwhile."""
    from redline.detect.corpus import CorpusError, first_executions, load_corpus
    from redline.detect.evaluate import change_point_f1, evaluate_corpus
    from redline.detect.registry import CHANGE_POINT_METHOD, EVALUATED

    chosen = [m.strip() for m in methods.split(",") if m.strip()] if methods else None
    unknown = sorted(set(chosen or []) - {*EVALUATED, CHANGE_POINT_METHOD})
    if unknown:
        typer.echo(
            f"evaluate: unknown method(s) {', '.join(unknown)}; known: "
            f"{', '.join([*EVALUATED, CHANGE_POINT_METHOD])}",
            err=True,
        )
        raise typer.Exit(2)
    if units is not None:
        try:  # before a run that may take minutes, not after it
            units.open("w").close()
        except OSError as exc:
            typer.echo(f"evaluate: cannot write --units {units}: {exc.strerror}", err=True)
            raise typer.Exit(2) from exc
    try:
        loaded = load_corpus(corpus)
    except (CorpusError, OSError, KeyError, ValueError) as exc:
        typer.echo(f"evaluate: cannot read corpus {corpus!r}: {exc}", err=True)
        raise typer.Exit(2) from exc
    if executions:
        loaded = first_executions(loaded, executions)
    if not json_output:
        typer.echo(f"{loaded.name}: {loaded.source}")
        typer.echo(HEADER)
    shown = {"at": 0.0}

    def progress(method: str, done: int, total: int) -> None:
        now = time.monotonic()
        if now - shown["at"] >= 2 or done == total:
            shown["at"] = now
            print(f"  {method}: {done}/{total} series", file=sys.stderr, flush=True)

    kept: dict[str, list[Outcome]] = {}

    def finished(name: str, scores: MethodScores, outcomes: list[Outcome]) -> None:
        if units is not None or f1:
            kept[name] = outcomes
        if not json_output:
            typer.echo(table_row(name, scores))

    results = evaluate_corpus(loaded, chosen, confirm, progress, finished)
    if units is not None:
        write_units(units, kept)
    points = change_point_f1(loaded, kept) if f1 else {}
    if json_output:
        typer.echo(as_json(results, confirm, points))
        return
    typer.echo(LEGEND)
    if points:
        typer.echo("change-point F1 (TCPDBench, margin 5, mean over series):")
        for name, value in points.items():
            typer.echo(f"  {name:<19} {value:.3f}")


def register(app: typer.Typer) -> None:
    app.command("evaluate")(evaluate_cmd)
