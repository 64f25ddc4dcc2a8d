"""`redline ci wait`: what a CI job runs after reporting a revision. It waits for the revision's
verdict (its jobs, their analysis, and confirmation runs), writes it as JUnit XML, prints a short
table, and says by its exit code whether the revision passes.

Exit codes: 0 no change (per ``--fail-on``), 1 a change, 2 bad input or timeout (unknown
component or revision, refused token, no verdict in time), 3 the revision's jobs failed, 4 no
change found but some test case undecided: the host was busy in every run of it or of its
baseline, even after a fresh run, its method failed, a measurement the revision before made
in it is missing, or the component took no part in its runs (no traffic) (never a silent pass;
``--fail-on none`` passes it); the message names which.
Only httpx is needed, so CI machines install the light `redline-agent` distribution.
"""

from __future__ import annotations

import json
import os
import sys
import time
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, NoReturn
from urllib.parse import quote, urlsplit

import httpx
import typer
from redline.cli.tokens import TokenFile, read_token

PASSED, CHANGED, BAD_INPUT, JOBS_FAILED, UNDECIDED = 0, 1, 2, 3, 4
#: how long a revision may take to appear (its push is still being reported) before "unknown"
APPEAR_S = 120.0

ci = typer.Typer(
    help="For CI pipelines: report a commit, wait for its verdict.", no_args_is_help=True
)


class FailOn(StrEnum):
    regression = "regression"
    any = "any"
    none = "none"


def _stop(code: int, message: str) -> NoReturn:
    typer.echo(f"redline ci wait: {message}", err=True)
    raise typer.Exit(code)


#: answers of a proxy whose server is down or restarting, or of the server while its database
#: is out of reach (503): waited for, as a refused connection is
UNAVAILABLE = (502, 503, 504)
#: how long the JUnit file is waited for once the verdict came at the end of the --timeout
JUNIT_GRACE_S = 30.0


def _get(client: httpx.Client, path: str, **params: str) -> httpx.Response | None:
    """The answer, or None when the server cannot be reached or its proxy says it is down
    (tried again later: behind nginx, a restarting server answers 502, not a refused
    connection, and a hiccup fetching the JUnit file exited 1, "a change")."""
    try:
        answer = client.get(path, params=params)
    except httpx.TransportError as error:
        why = type(error).__name__
    else:
        if answer.status_code not in UNAVAILABLE:
            return answer
        why = f"HTTP {answer.status_code}: {detail(answer)[:120]}"
    typer.echo(f"server {client.base_url} not reachable ({why}); trying again", err=True)
    return None


def no_token(answer: httpx.Response, token: str, scope: str) -> str:
    """What a 401 adds when no token was given (a trial read only "missing bearer token")."""
    if answer.status_code != 401 or token:
        return ""
    return f"; no token was given: set REDLINE_TOKEN to a token with the '{scope}' scope"


def detail(answer: httpx.Response) -> str:
    """The server's reason, a refused field's as ``field: message`` (not a list's repr)."""
    try:
        said = answer.json().get("detail", answer.text)
    except ValueError:
        return answer.text[:200]
    if isinstance(said, list):
        return "; ".join(
            f"{'.'.join(str(p) for p in item.get('loc', [])[1:])}: {item.get('msg', item)}"
            if isinstance(item, dict)
            else str(item)
            for item in said
        )
    return str(said)


def _counted(change: dict[str, Any], fail_on: FailOn) -> bool:
    return fail_on == FailOn.any or (fail_on == FailOn.regression and change["worse"])


def _params_text(params: object) -> str:
    """A case's parameter set as the JUnit names it (`redline.recording.format.
    canonical_params`'s text, written out: importing redline.recording loads the MCAP reader,
    which `ci wait` does without); a server before 2026-11-27 sent that text itself."""
    if isinstance(params, str):
        return params
    return json.dumps(params, sort_keys=True, separators=(",", ":"), default=str)


def _marks(change: dict[str, Any]) -> str:
    """What a change's row adds to its size: for the better, and not confirmed yet (a trial's
    console showed a suspected change as plainly failed; only its JUnit file said so)."""
    marks = [] if change["worse"] else ["better"]
    if change.get("confirmation") == "suspected":
        marks.append("suspected: not confirmed yet")
    if change.get("between"):  # revisions of its range that did not measure it
        marks.append(f"may be an earlier revision's: {change['between']}")
    return f" ({'; '.join(marks)})" if marks else ""


def _table(verdict: dict[str, Any], fail_on: FailOn) -> str:
    rows = [("test case / phase [parameters]", "verdict", "changes")]
    for case in verdict["cases"]:
        if case["state"] in ("passed", "failed"):  # as --fail-on counts
            failed = any(_counted(c, fail_on) for c in case["changes"])
            case = {**case, "state": "failed" if failed else "passed"}
        changes = ", ".join(
            f"{c['process']} {c['counter']} "
            + ("n/a" if c["effect"] is None else f"{c['effect'] * 100:+.1f} %")
            + _marks(c)
            for c in case["changes"]
        )
        name = f"{case['case']} / {case['phase']} {_params_text(case['parameters'])}".strip()
        if case["state"] in ("skipped", "undecided"):  # why first: a trial's skipped case
            # showed only an improvement, where the JUnit file said why it had no verdict
            changes = case["reason"] + (f"; also: {changes}" if changes else "")
        rows.append((name, case["state"], changes or case["reason"]))
    width = [max(len(row[i]) for row in rows) for i in range(2)]
    lines = [f"{a:<{width[0]}}  {b:<{width[1]}}  {c}" for a, b, c in rows]
    lines.append(
        f"{verdict['component']} {verdict['revision']}: {verdict['regressions']} change(s) for "
        f"the worse, {verdict['improvements']} for the better, {verdict['skipped']} test "
        f"case(s) without enough data"
        + (
            f", {verdict['undecided']} undecided (each case says why)"
            if verdict.get("undecided")
            else ""
        )
    )
    return "\n".join(lines)


def _open_before(verdict: dict[str, Any], server: str) -> str:
    """The regressions still open before the revision, which its own verdict does not count (a
    trial's commits after a suspected regression passed with no word of it)."""
    found = verdict["open_before"]
    total = verdict.get("open_before_total", len(found))
    lines = [
        f"{total} regression(s) still open before this revision (not counted in its verdict: "
        "it carries them unless it undid them; triage them on their pages):"
    ]
    lines += [
        f"  #{r['id']} {r['confirmation']}, triage {r['state']}: after {r['good_revision']}, "
        f"shows at {r['bad_revision']}: {r['largest']}"
        + (f"; {r['changed_back']}" if r.get("changed_back") else "")
        + f"  {server}{r['page']}"
        for r in found
    ]
    if total > len(found):
        listed = f"{server}/regressions?component={quote(verdict['component'])}"
        lines.append(f"  and {total - len(found)} more, among the component's: {listed}")
    return "\n".join(lines)


#: how much of each undecided case's reason the exit message quotes
REASON_CHARS = 300


def _undecided_message(verdict: dict[str, Any]) -> str:
    """Why the revision is undecided, in its own cases' words (a trial's verdict, undecided
    because a measurement was missing, was said to be a busy host or a failed method)."""
    reasons = [
        f"{case['case']} / {case['phase']} {_params_text(case['parameters'])}: {case['reason']}"
        for case in verdict.get("cases", [])
        if case.get("state") == "undecided"
    ]
    said = "; ".join(
        reason if len(reason) <= REASON_CHARS else reason[: REASON_CHARS - 1] + "…"
        for reason in reasons[:3]
    )
    more = f"; and {len(reasons) - 3} more" if len(reasons) > 3 else ""
    return f"{verdict['undecided']} test case(s) undecided: {said}{more}; see the page"


def _junit_error(path: Path, component: str, revision: str, message: str) -> None:
    """A JUnit file that says why there is no verdict (so a CI step keeping it finds one)."""
    from xml.sax.saxutils import quoteattr

    from redline.recording.xml_text import xml_safe

    path.write_text(
        xml_safe(
            '<?xml version="1.0" encoding="utf-8"?>\n'
            f'<testsuite name={quoteattr("redline." + component)} tests="1" failures="0" '
            f'errors="1" skipped="0"><testcase classname={quoteattr("redline." + component)} '
            f"name={quoteattr(revision + ' verdict')}><error message={quoteattr(message)}/>"
            "</testcase></testsuite>\n"
        )
    )


def unaddressable(option: str, name: str) -> str | None:
    """Why no API address can carry the name, or None (a trial's ``--revision ..`` and
    ``--component ../x`` were told only "Not Found")."""
    if name in ("", ".", "..") or "/" in name:
        return (
            f"{option} {name!r}: not a name Redline gives anything: a component's name or a "
            "revision's title is not empty, '.' or '..', and has no '/'"
        )
    return None


def _writable(path: Path) -> None:
    """Exit 2 now, not after the wait, when the JUnit file cannot be written; a missing folder
    is made, as `redline run --out` and `redline compare --junit` make theirs (a trial met all
    three, and only this one refused)."""
    folder = path.parent if str(path.parent) else Path(".")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _stop(BAD_INPUT, f"--junit {path}: no folder {folder} can be made: {exc.strerror or exc}")
    if path.is_dir() or not os.access(folder, os.W_OK):
        _stop(BAD_INPUT, f"--junit {path}: cannot be written")


def _write(path: Path, xml: str) -> None:
    try:
        path.write_text(xml)
    except OSError as error:
        _stop(BAD_INPUT, f"--junit {path}: {error}")


def wait(
    server: Annotated[str, typer.Option(help="URL of the Redline server", envvar="REDLINE_SERVER")],
    component: Annotated[str, typer.Option(help="the component's name")],
    revision: Annotated[
        str | None,
        typer.Option(
            help="the revision's title, or its commit's hash, full or abbreviated (default: "
            "HEAD's first 12 digits, as `ci report` gives it)"
        ),
    ] = None,
    token_file: TokenFile = None,
    junit: Annotated[Path | None, typer.Option(help="write the verdict as JUnit XML here")] = None,
    timeout: Annotated[float, typer.Option(min=1, help="seconds to wait for the verdict")] = 3600,
    fail_on: Annotated[
        FailOn,
        typer.Option(help="what fails: a change for the worse, any change, or nothing"),
    ] = FailOn.regression,
    poll: Annotated[float, typer.Option(min=0.1, help="seconds between two looks")] = 10.0,
) -> None:
    """Wait for a revision's verdict; write JUnit XML; exit 0 (no change), 1 (change), 2 (bad
    input or timeout), 3 (its jobs failed), 4 (undecided: the host was busy, a method
    failed, a measurement went missing, or the component took no part in the run)."""
    if junit is not None:
        _writable(junit)

    def fail(message: str) -> NoReturn:
        """Exit 2 with ``message``, in the JUnit file too: a CI step keeps it in every case."""
        if junit is not None:
            _junit_error(junit, component, revision or "HEAD", message)
        _stop(BAD_INPUT, message)

    if revision is None:
        from redline.cli.ci_report import TITLE_DIGITS, NoCommit, git_head

        try:
            revision = git_head("%H")[:TITLE_DIGITS]
        except NoCommit as exc:
            fail(f"{exc} (--revision)")

    if urlsplit(server).scheme not in ("http", "https") or not urlsplit(server).hostname:
        fail(f"--server {server!r}: not an http:// or https:// URL")
    for option, name in (("--component", component), ("--revision", revision)):
        if (why := unaddressable(option, name)) is not None:
            fail(why)

    try:
        token = read_token(token_file, required=False)
    except typer.BadParameter as exc:  # in the JUnit file too (a reviewer's find)
        fail(f"{exc.param_hint or '--token-file'}: {exc.message}")
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    base = f"/api/v1/components/{quote(component, safe='')}/revisions/{quote(revision, safe='')}"
    started = time.monotonic()
    said, reached = "", False
    wanted = {} if junit is None else {"junit": fail_on.value}
    settled = False  # a verdict came: read again with its JUnit XML, of one reading
    with httpx.Client(base_url=server.rstrip("/"), headers=headers, timeout=30) as client:
        while True:
            waited = time.monotonic() - started
            # with the JUnit XML once settled, when it is wanted: both of one reading, one
            # request (not at every poll: the server would build the XML each time)
            answer = _get(client, f"{base}/verdict", **(wanted if settled else {}))
            reached = reached or answer is not None
            if answer is not None:
                if answer.status_code in (401, 403):
                    fail(
                        f"the server refused the token: {detail(answer)}"
                        + no_token(answer, token, "read' or 'ci")
                    )
                if answer.status_code == 404:
                    missing = detail(answer)
                    if missing == "Not Found":  # no route at all: not Redline's API there
                        fail(f"{server} has no Redline API at {base}/verdict: is --server the "
                             "root URL of the Redline server?")  # fmt: skip
                    if "has no revision" not in missing:
                        fail(missing)
                    if waited > min(APPEAR_S, timeout):  # said as the timeout below says it
                        fail(
                            f"no verdict within {min(APPEAR_S, timeout):.0f} s: still waiting "
                            f"for the revision to be reported ({missing})"
                        )
                    if not said:  # a trial sat two silent minutes here
                        said = "the revision to be reported"
                        limit = min(APPEAR_S, timeout)
                        typer.echo(f"{missing} yet: waiting up to {limit:.0f} s for it", err=True)
                elif answer.status_code != 200:
                    fail(f"HTTP {answer.status_code}: {detail(answer)}")
                else:
                    verdict = answer.json()
                    # pending again (results came in meanwhile): polled without the XML again
                    settled = settled and verdict["state"] != "pending"
                    if verdict["state"] != "pending" and wanted and not settled:
                        settled = True
                        continue  # at once, with its JUnit XML
                    if verdict["state"] != "pending":
                        # the waits said on stderr, before the table on stdout: how long it took
                        typer.echo(f"verdict after {waited:.0f} s of waiting", err=True)
                        break
                    if verdict["waiting_for"] != said:
                        said = verdict["waiting_for"]
                        typer.echo(f"waiting for {said} (at {waited:.0f} s)", err=True)
            if not reached and waited > min(APPEAR_S, timeout):
                fail(
                    f"the server at {server} was not reached in {waited:.0f} s: is --server right?"
                )
            if waited + poll > timeout:
                if said:
                    why = f"still waiting for {said}"
                elif reached:
                    why = "the revision did not appear"
                else:
                    why = f"the server at {server} was never reached"
                fail(f"no verdict within {timeout:.0f} s: {why}")
            time.sleep(poll)
        if junit is not None and verdict.get("junit") is not None:
            _write(junit, verdict["junit"])
        elif junit is not None:  # a server from before the XML came with the verdict
            deadline = time.monotonic() + max(timeout - waited, JUNIT_GRACE_S)
            while (xml := _get(client, f"{base}/junit", fail_on=fail_on.value)) is None:
                if time.monotonic() + poll > deadline:
                    fail(f"the verdict came, but not its JUnit file: {server} not reachable")
                time.sleep(poll)
            if xml.status_code != 200:
                fail(f"the verdict came, but not its JUnit file: HTTP {xml.status_code}: "
                     f"{detail(xml)}")  # fmt: skip
            _write(junit, xml.text)
    if verdict["state"] == "failed":  # no verdict: no table of counts that would read as one
        typer.echo(f"page: {server.rstrip('/')}{verdict['page']}")
        _stop(JOBS_FAILED, f"the revision's performance jobs failed: {verdict['reason']}")
    typer.echo(_table(verdict, fail_on))
    if verdict.get("open_before"):
        typer.echo(_open_before(verdict, server.rstrip("/")))
    typer.echo(f"page: {server.rstrip('/')}{verdict['page']}")
    changed = {
        FailOn.regression: verdict["regressions"],
        FailOn.any: verdict["regressions"] + verdict["improvements"],
        FailOn.none: 0,
    }[fail_on]
    sys.stdout.flush()
    if changed:
        raise typer.Exit(CHANGED)
    if verdict.get("undecided") and fail_on != FailOn.none:
        _stop(UNDECIDED, _undecided_message(verdict))
    raise typer.Exit(PASSED)


def register(app: typer.Typer) -> None:
    from redline.cli.ci_report import report

    ci.command("report")(report)
    ci.command("wait")(wait)
    app.add_typer(ci, name="ci")
