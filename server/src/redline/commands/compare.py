"""`redline compare`: KS per series between recordings, as JUnit XML and an HTML report.

    redline compare --baseline A.mcap [A2.mcap ...] --candidate B.mcap [B2.mcap ...]
                    --junit out.xml [--html out.html]

Exit status: 1 when a change for the worse is found; 4 when none is but something could not be
judged: a series only the baseline holds (its action path changed, or its report is missing from
every candidate run: the comparison lost a measurement), or a segment the host was busy in (as
`redline ci wait`: what was not measured must not pass); 0 otherwise; 2 on bad
input (an unreadable or truncated recording, named; no series in common; a malformed command
line). A series only the candidate holds (a new test or action) is listed, never a failure.

The comparison (scipy) is imported where it runs, not here: every `redline` command line imports
this module to build the CLI.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from typer.core import TyperCommand, TyperOption

if TYPE_CHECKING:
    from redline.detect.comparison import Comparison, SegmentVerdict
    from typer._click.core import Context  # the Context typer vendors from click

EXIT_CHANGE, EXIT_BAD_INPUT, EXIT_NOT_JUDGED = 1, 2, 4


@dataclass
class CompareArgs:
    baseline: list[Path] = field(default_factory=list)
    candidate: list[Path] = field(default_factory=list)
    junit: Path | None = None
    html: Path | None = None
    judge_split: bool = False


class FilesAfterOption(TyperCommand):
    """A command whose repeatable options also take every further file that follows them:
    ``--baseline A B`` reads as ``--baseline A --baseline B``."""

    def parse_args(self, ctx: Context, args: list[str]) -> list[str]:
        return super().parse_args(ctx, self.repeat_options(ctx, args))

    def repeat_options(self, ctx: Context, args: list[str]) -> list[str]:
        options = [param for param in self.params if isinstance(param, TyperOption)]
        repeatable = {name for option in options if option.multiple for name in option.opts}
        valued = {name for option in options if not option.is_flag for name in option.opts}
        words: list[str] = []
        current: str | None = None  # the repeatable option that a bare file name belongs to
        awaiting: str | None = None  # the option whose value the next word is
        for word in args:
            is_option = word.startswith("-")
            if awaiting:
                if is_option:  # Click would take this option's name for the file's
                    raise typer.BadParameter("needs a file name", ctx, param_hint=awaiting)
                words.append(word)
                awaiting = None
            elif is_option:
                name = word.partition("=")[0]
                current = name if name in repeatable else None
                awaiting = name if name in valued and "=" not in word else None
                words.append(word)
            else:
                words += [current, word] if current else [word]
        return words


def compare_cmd(
    baseline: Annotated[
        list[Path],
        typer.Option(
            metavar="FILE.mcap ...",
            help="baseline recording(s): every file after the option (it may also repeat)",
        ),
    ],
    candidate: Annotated[
        list[Path],
        typer.Option(
            metavar="FILE.mcap ...", help="candidate recording(s), given as the baseline's"
        ),
    ],
    junit: Annotated[
        Path,
        typer.Option(help="the JUnit XML to write: a test case per case, phase and parameter set"),
    ],
    html: Annotated[
        Path | None, typer.Option(help="also an HTML report plotting the changed counters")
    ] = None,
    judge_split: Annotated[
        bool,
        typer.Option(
            help="judge the context counters too: the user/system split of CPU and involuntary "
            "context switches (by default not: they move between runs of the same code)"
        ),
    ] = False,
) -> None:
    """Compare candidate recordings with baseline ones: KS per counter series, JUnit XML out.

    Exit 1 when a change for the worse is found; 4 when none is but something was not judged (a
    series only the baseline holds, a segment the host was busy in); 0 otherwise; 2 on bad input.
    """
    from redline.detect.compare import CompareError, compare_files
    from redline.detect.compare_junit import series_line
    from redline.detect.counters import CONTEXT_COUNTERS
    from redline.recording.disturbance import threshold

    args = CompareArgs(baseline, candidate, junit, html, judge_split)
    try:
        comparison = compare_files(
            args.baseline, args.candidate, () if args.judge_split else CONTEXT_COUNTERS, threshold()
        )
        write_outputs(comparison, args)
    except CompareError as exc:
        typer.echo(f"compare: {exc}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except OSError as exc:
        typer.echo(f"compare: cannot write {exc.filename}: {exc.strerror}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    for recorded in (*comparison.baseline, *comparison.candidate):
        for (case, phase, params), why in recorded.disturbed.items():
            typer.echo(
                f"warning: {recorded.label}: {case}/{phase} {params}: {why} (of its "
                "measurements only what the component holds is judged: memory, threads, files)",
                err=True,
            )
    changed, lost = comparison.changed, comparison.lost
    for segment in comparison.segments:
        typer.echo(f"{segment.name}: {segment_marks(segment)}")
        for verdict in segment.changed:  # which counters, by how much
            typer.echo(f"  {series_line(verdict)}")
        for verdict in (*segment.lost, *segment.too_few, *segment.new):
            key, result = verdict.key, verdict.result
            typer.echo(f"  {key.process}.{key.counter}: {result.verdict} ({result.reason})")
    worse = sum(1 for segment in comparison.segments if segment.changed)
    typer.echo(
        f"{len(changed)} counter(s) changed for the worse in {worse} of "
        f"{len(comparison.segments)} segment(s), {len(comparison.improved)} improved"
        + (f", {len(lost)} only in the baseline (not judged)" if lost else "")
        + _busy_summary(comparison)
        + f"; JUnit: {args.junit}"
        + (f"; HTML: {args.html}" if args.html else "")
    )
    if changed:
        raise typer.Exit(EXIT_CHANGE)
    if lost or comparison.busy or comparison.too_few:
        raise typer.Exit(EXIT_NOT_JUDGED)


def _busy_summary(comparison: Comparison) -> str:
    """How many segments the host was busy in: not judged, or judged only in what the
    component holds."""
    part = sum(1 for segment in comparison.busy if segment.in_part)
    none = len(comparison.busy) - part
    return (f", {none} segment(s) not judged (the host was busy)" if none else "") + (
        f", {part} segment(s) judged in part (the host was busy)" if part else ""
    )


def segment_marks(segment: SegmentVerdict) -> str:
    """How the console shows a segment: ``CHANGED (1), improved (2)``, ``NOT JUDGED (3 only
    in the baseline)``, ``ok`` or why it was not compared."""
    marks = [f"CHANGED ({len(segment.changed)})"] if segment.changed else []
    marks += [f"improved ({len(segment.improved)})"] if segment.improved else []
    marks += [f"NOT JUDGED ({len(segment.lost)} only in the baseline)"] if segment.lost else []
    marks += [f"NOT JUDGED ({len(segment.too_few)} too few to decide)"] if segment.too_few else []
    marks += [f"new ({len(segment.new)} only in the candidate)"] if segment.new else []
    return ", ".join([*marks, *([segment.note] if segment.note else [])]) or "ok"


def write_outputs(comparison: Comparison, args: CompareArgs) -> None:
    from redline.detect.compare_junit import junit_xml

    assert args.junit is not None
    args.junit.write_text(junit_xml(comparison), encoding="utf-8")
    if args.html is not None:
        # plotly only when a report is asked for
        from redline.commands.compare_report import html_report

        args.html.write_text(html_report(comparison), encoding="utf-8")


def register(app: typer.Typer) -> None:
    app.command("compare", cls=FilesAfterOption)(compare_cmd)


def parse_args(argv: list[str]) -> CompareArgs:
    """A `redline compare` command line as the command reads it. Raises CompareError naming
    what is wrong."""
    from redline.detect.compare import CompareError

    app = typer.Typer()
    register(app)
    try:
        ctx = typer.main.get_command(app).make_context("compare", list(argv))
    except typer.TyperException as exc:  # Click's usage errors
        raise CompareError(exc.format_message()) from None
    return CompareArgs(**ctx.params)
