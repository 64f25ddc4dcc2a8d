"""`redline ci report`: what a CI job runs first, to report the commit it built to the server.

Run in the component's git work tree, it reports HEAD: its full id as the commit the
performance hosts build, its first 12 hex digits as the title, its commit time as the sort key,
its message and time; each can be given instead (``--commit``, ``--title``, ...). It prints the
title on stdout, for `redline ci wait --revision`, which takes the same default. A commit
reported before is the same revision (exit 0: a re-run pipeline, or CI and a webhook both).
Exit codes: 0 reported, 2 refused (the server's reason) or nothing to report. Before this
command, CI reported with curl and a here-document (docs/ci.md).
"""

from __future__ import annotations

import os
import subprocess
from typing import Annotated, Any, NoReturn
from urllib.parse import urlsplit

import httpx
import typer
from redline.cli.ci_cmd import BAD_INPUT, detail, no_token, unaddressable
from redline.cli.tokens import TokenFile, read_token
from redline.recording.format import COMMIT_HASH

#: a title of the first 12 hex digits, as `git rev-parse --short=12` and the push webhook give
TITLE_DIGITS = 12


def _stop(message: str) -> NoReturn:
    typer.echo(f"redline ci report: {message}", err=True)
    raise typer.Exit(BAD_INPUT)


class NoCommit(ValueError):
    """No commit to report or wait for here: the message says why and what to give instead."""


def git_head(what: str, commit: str = "HEAD") -> str:
    """``git log -1 --format=WHAT COMMIT`` in the working directory; `NoCommit` outside a
    work tree or for a commit it does not have."""
    if commit.startswith("-"):  # git would take it for an option (--output=FILE writes)
        raise NoCommit(f"--commit {commit!r}: not a commit")
    try:
        done = subprocess.run(
            ["git", "log", "-1", f"--format={what}", commit, "--"],
            capture_output=True,
            text=True,
            timeout=30,
        )
    except FileNotFoundError:
        raise NoCommit("git is not installed: give the commit and title yourself") from None
    if done.returncode != 0:
        said = done.stderr.strip().splitlines()[-1] if done.stderr.strip() else ""
        raise NoCommit(
            f"cannot read commit {commit!r} here ({said}): run in the component's git work "
            "tree, or name the commit and title yourself"
        )
    return done.stdout.rstrip("\n")


def git_remotes() -> list[str]:
    """The work tree's remote URLs, user names and passwords left out (a CI runner's origin
    holds its job token: ``https://gitlab-ci-token:<token>@host/...``); none outside one."""
    try:
        done = subprocess.run(
            ["git", "config", "--get-regexp", r"^remote\..*\.url$"],
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (FileNotFoundError, subprocess.TimeoutExpired):
        return []
    return [_local_made_absolute(_without_credentials(line.partition(" ")[2].strip()))[:2000]
            for line in done.stdout.splitlines()[:20]]  # fmt: skip


def _local_made_absolute(url: str) -> str:
    """A local path (no scheme, no ``host:`` before its first ``/``) as an absolute one: git
    reads ``../comp`` from the work tree, the server cannot."""
    if "://" in url or ":" in url.split("/")[0] or not url:
        return url
    return os.path.abspath(url)


def _without_credentials(url: str) -> str:
    """``url`` without what could hold a secret: whatever precedes its last ``@`` (a user and
    a password, which may hold a ``/``), its query and its fragment (``?access_token=``)."""
    scheme, sep, rest = url.partition("://")
    rest = (rest if sep else url).rpartition("@")[2].split("?")[0].split("#")[0]
    return f"{scheme}://{rest}" if sep else rest


def report(
    component: Annotated[str, typer.Option(help="the component's name")],
    server: Annotated[str, typer.Option(help="URL of the Redline server", envvar="REDLINE_SERVER")],
    token_file: TokenFile = None,
    commit: Annotated[
        str, typer.Option(help="what the hosts build (default: HEAD's full id)")
    ] = "",
    title: Annotated[
        str, typer.Option(help="the revision's title (default: the commit's first 12 digits)")
    ] = "",
    sort_key: Annotated[
        str, typer.Option(help="orders revisions (default: the commit's time, in seconds)")
    ] = "",
    branch: Annotated[str, typer.Option(help="default: the component's branch")] = "",
) -> None:
    """Report a commit to the server: the hosts measure it, `redline ci wait` waits for it."""
    if urlsplit(server).scheme not in ("http", "https") or not urlsplit(server).hostname:
        _stop(f"--server {server!r}: not an http:// or https:// URL")
    if (why := unaddressable("--component", component)) is not None:
        _stop(why)
    given = [option for option, value in (("--title", title), ("--sort-key", sort_key)) if value]
    body: dict[str, Any] = {"component": component, "branch": branch}
    # what is not given comes from git, and so does the hash of a commit named otherwise: the
    # server takes a commit by its hash only (a branch or tag moves)
    if not (commit and title and sort_key) or not COMMIT_HASH.fullmatch(commit):
        try:
            head = git_head("%H%n%ct%n%cI%n%B", commit or "HEAD")
        except NoCommit as exc:
            _stop(f"{exc} (--commit as its hash, 7 to 64 hex digits, --title and --sort-key)")
        full, when, stamp, *message = head.split("\n", 3)  # a message may be empty
        body |= {"message": "".join(message)[:10_000], "committed_at": stamp}
        # the full id git resolved (HEAD~1 or main was refused, or taken for another commit)
        commit, title, sort_key = full, title or full[:TITLE_DIGITS], sort_key or when
    body |= {"commit": commit, "title": title, "sort_key": sort_key}
    if remotes := git_remotes():  # for the server to say when they are not the component's
        body["remotes"] = remotes
    token = read_token(token_file, required=False)
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    url = f"{server.rstrip('/')}/api/v1/revisions"
    try:
        answer = httpx.post(url, json=body, headers=headers, timeout=60)
        if answer.status_code == 422 and "remotes" in body and "remotes" in answer.text:
            body.pop("remotes")  # a server from before `remotes`: reported again without them
            answer = httpx.post(url, json=body, headers=headers, timeout=60)
    except httpx.TransportError as error:
        said = str(error).replace(token, "<token>") if token else str(error)  # never echoed
        _stop(f"the server at {server} cannot be reached ({type(error).__name__}: {said})")
    if answer.status_code not in (200, 201):
        _stop(f"HTTP {answer.status_code}: {detail(answer)}" + no_token(answer, token, "ci"))
    said = answer.json()
    jobs, title = len(said.get("job_ids", [])), said.get("title", title)  # the first report's
    # a revision keeps its first report's title and sort key: say so where others were given
    # (a trial's --title on a known commit got the old title back, and no word)
    kept = (
        f"; {' and '.join(given)} not applied: a revision keeps its first report's title and "
        "sort key (an admin corrects a sort key: PATCH "
        f"/api/v1/components/{component}/revisions/{title})"
        if answer.status_code == 200 and given
        else ""
    )
    if said.get("warning"):
        typer.echo(f"redline ci report: warning: {said['warning']}", err=True)
    typer.echo(
        f"{component} {title}: reported before with this commit ({jobs} job(s)){kept}"
        if answer.status_code == 200
        else f"{component} {title} reported: {jobs} job(s) queued",
        err=True,
    )
    typer.echo(title)
