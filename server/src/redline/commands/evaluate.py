"""`redline evaluate CORPUS`: each detector's accuracy on a labelled corpus.

The detectors (scipy) and the corpus (pandas) are imported where they are used, not here: every
`redline` command line imports this module to build the CLI.
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from redline.detect.evaluate import MethodScores

METRICS = ("roc_auc", "precision", "recall", "f1")


def _number(value: float) -> float | None:
    return None if math.isnan(value) else round(value, 4)


def as_json(results: dict[str, MethodScores]) -> str:
    """``{"default": METHOD, "methods": {METHOD: {"roc_auc", "precision", "recall", "f1"}}}``."""
    from redline.detect.registry import DEFAULT_METHOD

    methods = {
        name: {metric: _number(getattr(scores, metric)) for metric in METRICS}
        for name, scores in results.items()
    }
    return json.dumps({"default": DEFAULT_METHOD, "methods": methods})


def as_table(results: dict[str, MethodScores]) -> str:
    from redline.detect.registry import DEFAULT_METHOD

    header = (
        f"{'method':<16}{'ROC-AUC':>8}{'prec.':>7}{'recall':>7}{'F1':>7}"
        f"{'TP':>5}{'FP':>5}{'FN':>5}{'FA/100':>8}{'rec>=10%':>10}{'decided':>14}"
    )
    lines = [header]
    for name, s in results.items():
        mark = " *" if name == DEFAULT_METHOD else ""
        large = f"{s.recall_large:.2f} ({s.large})" if s.large else "-"
        lines.append(
            f"{name:<16}{s.roc_auc:>8.3f}{s.precision:>7.3f}{s.recall:>7.3f}"
            f"{s.f1:>7.3f}{s.tp:>5}{s.fp:>5}{s.fn:>5}{s.false_alarms_per_100:>8.1f}"
            f"{large:>10}{s.decided:>7}/{s.units:<6}{mark}"
        )
    lines.append(
        "* default method; FA/100: false alarms per 100 unchanged builds; rec>=10%: "
        "recall of the changes of 10 % or more (how many); 'decided' = units not "
        "answered 'not enough data'"
    )
    return "\n".join(lines)


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
) -> None:
    """ROC-AUC, precision, recall and F1 of every detection method on a labelled corpus."""
    from redline.detect.corpus import CorpusError, first_executions, load_corpus
    from redline.detect.evaluate import evaluate_corpus
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
    try:
        loaded = load_corpus(corpus)
    except (CorpusError, OSError, KeyError, ValueError) as exc:
        typer.echo(f"evaluate: cannot read corpus {corpus!r}: {exc}", err=True)
        raise typer.Exit(2) from exc
    if executions:
        loaded = first_executions(loaded, executions)
    results = evaluate_corpus(loaded, chosen, confirm)
    if json_output:
        typer.echo(as_json(results))
        return
    typer.echo(f"{loaded.name}: {loaded.source}")
    typer.echo(as_table(results))


def register(app: typer.Typer) -> None:
    app.command("evaluate")(evaluate_cmd)
