"""`redline ci report`'s remotes: what it sends the server of the work tree's remote URLs."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from redline.cli.ci_report import git_remotes


def test_remotes_are_sent_without_user_names_or_passwords(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A CI runner's origin holds its job token (GitLab: https://gitlab-ci-token:<token>@...):
    it must never leave the runner in a report."""
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True, env=env)
    for name, url in (
        ("origin", "https://gitlab-ci-token:glcbt-s3cret@gitlab.example/group/app.git"),
        ("mirror", "git@github.com:group/app.git"),
        ("plain", "https://user@github.com/group/app"),
        ("slash", "https://u:ab/cd@git.example/x.git"),  # a password with a slash in it
        ("query", "https://git.example/y.git?access_token=tok#frag"),
        ("ssh", "ssh://user:pw@git.example:2222/z.git"),
        ("scp", "user:tok@git.example:w.git"),
    ):
        subprocess.run(["git", "remote", "add", name, url], cwd=tmp_path, check=True, env=env)
    monkeypatch.chdir(tmp_path)
    remotes = git_remotes()
    assert sorted(remotes) == [
        "git.example:w.git",
        "github.com:group/app.git",
        "https://git.example/x.git",
        "https://git.example/y.git",
        "https://github.com/group/app",
        "https://gitlab.example/group/app.git",
        "ssh://git.example:2222/z.git",
    ]
    sent = " ".join(remotes)
    assert not any(secret in sent for secret in ("s3cret", "ab/cd", "tok", "pw", "user", "u:"))


def test_a_relative_local_remote_is_sent_as_an_absolute_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A trial's clone of ../comp was reported as '/../comp', which names nothing."""
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    tree = tmp_path / "tree"
    tree.mkdir()
    subprocess.run(["git", "init", "-q"], cwd=tree, check=True, env=env)
    subprocess.run(["git", "remote", "add", "origin", "../comp"], cwd=tree, check=True, env=env)
    monkeypatch.chdir(tree)
    assert git_remotes() == [str(tmp_path / "comp")]


def test_outside_a_work_tree_there_are_no_remotes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path))
    assert git_remotes() == []
