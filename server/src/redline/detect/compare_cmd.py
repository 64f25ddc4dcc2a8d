"""`redline compare`: KS per series between recordings, as JUnit XML and an HTML report.

    redline compare --baseline A.mcap [A2.mcap ...] --candidate B.mcap [B2.mcap ...]
                    --junit out.xml [--html out.html]

Exit status: 1 when a change is found, 0 when none is, 2 on bad input (an unreadable or
truncated recording, named; no series in common; a malformed command line).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import typer
from redline.detect.compare import CompareError, Comparison, compare_files
from redline.detect.compare_junit import junit_xml

EXIT_CHANGE, EXIT_BAD_INPUT = 1, 2
_LISTS = ("--baseline", "--candidate")
_SINGLE = ("--junit", "--html")


@dataclass
class CompareArgs:
    baseline: list[Path] = field(default_factory=list)
    candidate: list[Path] = field(default_factory=list)
    junit: Path | None = None
    html: Path | None = None


def parse_args(argv: list[str]) -> CompareArgs:
    """``--baseline``/``--candidate`` take one or more files each (and may repeat);
    ``--junit`` and ``--html`` take one. Raises CompareError naming what is wrong."""
    args, current = CompareArgs(), ""
    for index, word in enumerate(argv):
        option, _, inline = word.partition("=") if word.startswith("--") else ("", "", "")
        if option in _LISTS:
            current = option
            if inline:
                getattr(args, option[2:]).append(Path(inline))
        elif option in _SINGLE:
            value = inline or (argv[index + 1] if index + 1 < len(argv) else "")
            if not value or value.startswith("--"):
                raise CompareError(f"{option} needs a file name")
            setattr(args, option[2:], Path(value))
            current = option
        elif word.startswith("-"):
            raise CompareError(
                f"unknown option {word!r} (expected --baseline, --candidate, --junit, --html)"
            )
        elif current in _LISTS:
            getattr(args, current[2:]).append(Path(word))
        elif current in _SINGLE and argv[index - 1] == current:
            continue  # the value of --junit / --html, taken above
        else:
            raise CompareError(f"{word!r}: a file must follow --baseline or --candidate")
    if args.junit is None:
        raise CompareError("--junit FILE is required")
    return args


def write_outputs(comparison: Comparison, args: CompareArgs) -> None:
    assert args.junit is not None
    args.junit.write_text(junit_xml(comparison), encoding="utf-8")
    if args.html is not None:
        from redline.worker.report import html_report  # plotly only when a report is asked for

        args.html.write_text(html_report(comparison), encoding="utf-8")


def compare_cmd(ctx: typer.Context) -> None:
    """Compare candidate recordings with baseline ones: KS per counter series, JUnit XML out.

    redline compare --baseline A.mcap [...] --candidate B.mcap [...] --junit out.xml
    [--html out.html]. Exit 1 when a change is found, 0 when none, 2 on bad input.
    """
    try:
        args = parse_args(list(ctx.args))
        comparison = compare_files(args.baseline, args.candidate)
        write_outputs(comparison, args)
    except CompareError as exc:
        typer.echo(f"compare: {exc}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except OSError as exc:
        typer.echo(f"compare: cannot write {exc.filename}: {exc.strerror}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    changed = comparison.changed
    for segment in comparison.segments:
        mark = f"CHANGED ({len(segment.changed)})" if segment.changed else segment.note or "ok"
        typer.echo(f"{segment.name}: {mark}")
    typer.echo(
        f"{len(changed)} counter(s) changed in {len(comparison.segments)} segment(s); "
        f"JUnit: {args.junit}" + (f"; HTML: {args.html}" if args.html else "")
    )
    if changed:
        raise typer.Exit(EXIT_CHANGE)


def register(app: typer.Typer) -> None:
    app.command(
        "compare", context_settings={"allow_extra_args": True, "ignore_unknown_options": True}
    )(compare_cmd)
