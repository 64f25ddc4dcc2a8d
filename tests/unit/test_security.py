"""Least privilege at the edges, without a service: where a performance host's code may come
from (real git, local repositories), how repository URLs compare, and that what charts and logs
show is text with no credentials."""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from pathlib import Path

import pytest
from redline.agent.checkout import CheckoutError, CloneCache, refused_repo
from redline.server.core.logs import URL_LOGGERS
from redline.server.schemas.results import SeriesOut
from redline.server.services.repos import repo_key

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


def test_chart_labels_are_text_not_markup():
    from redline.server.ui.figures import trend_figure

    link = '<a href="https://evil.example/phish">click</a>'
    series = SeriesOut(
        id=1,
        label=f"{link} / main",
        case=link,
        phase="main",
        params={},
        process="p",
        counter=link,
        kind="counter",
        worse="increase",
        judged=True,
        points=[{"revision": link, "sort_key": "1", "n": 3, "mean": 1.0, "std": 0.1}],
    )
    figure = json.dumps(trend_figure(series, []))
    assert "<a" not in figure and "&lt;a href" in figure


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
