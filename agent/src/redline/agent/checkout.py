"""A cache of clones on the performance host: one mirror per repository, one work tree per job.

A mirror holds the repository's branches and tags only (`REFSPECS`): a commit that only a pull
or merge request holds is not in it, so a revision naming one fails instead of running code
that nobody with push access put into the repository.

The repository and commit come from the server, so git is never handed them where it could read
an option: URLs are checked against the schemes a performance host fetches from (https, ssh, git,
and local paths only when allowed), git itself is told to refuse every other transport, and a
commit is resolved with ``--end-of-options`` before it is checked out.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
from pathlib import Path
from urllib.parse import urlsplit

from redline.recording.format import COMMIT_HASH

SCHEMES = ("https", "ssh", "git")
#: What a mirror holds: branches and tags, which only those who may push to the repository
#: write. Not every ref (``clone --mirror``): GitHub's ``refs/pull/*`` and GitLab's
#: ``refs/merge-requests/*`` hold the commits of anyone who opens a pull request, and a revision
#: naming one of those must not get it built and run on a performance host.
REFSPECS = ("+refs/heads/*:refs/heads/*", "+refs/tags/*:refs/tags/*")
#: the first ref (of those named after it) that holds a commit
REACHED_FROM = ("for-each-ref", "--count=1", "--format=%(refname)", "--contains")
_TRANSPORT = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*)::")  # git's <transport>::<address>
_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*)://")
#: user@host:path, ssh's short form; neither user nor host may start with '-' (an ssh option)
_SCP_LIKE = re.compile(r"^(?:[\w.][\w.-]*@)?[\w.][\w.-]*:(?!//)")


class CheckoutError(RuntimeError):
    """git could not produce the requested revision; the message carries git's own words."""


#: a URL's user information (``user:token@``), right after its scheme
_USERINFO = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*://)[^/]*@")  # to its last '@' ('p@ss')


def without_credentials(url: str) -> str:
    """``url`` as it may be shown: its user information (a user, a password, a token) left
    out."""
    return _USERINFO.sub(r"\1", url)


def refused_repo(url: str, allow_file: bool) -> str | None:
    """Why a performance host must not fetch ``url``, or None when it may.

    Allowed: ``https://``, ``ssh://``, ``git://`` and ssh's ``user@host:path``; a local path or
    ``file://`` URL only with ``allow_file``. Never: anything git could read as an option (a
    leading ``-``), its ``ext::``/``fd::`` transports, plain http, relative paths.
    """
    schemes = ", ".join((*SCHEMES, "file") if allow_file else SCHEMES)
    if not url:
        return "no repository is configured"
    if url != url.strip() or any(ord(char) < 32 or ord(char) == 127 for char in url):
        return "a repository URL may not hold whitespace or control characters"
    if url.startswith("-"):
        return "a repository URL must not start with '-' (git would read it as an option)"
    if (match := _TRANSPORT.match(url)) is not None:  # remote helpers run programs
        return f"scheme {match.group(1)!r} is not allowed (allowed: {schemes})"
    if (match := _URL.match(url)) is not None:
        scheme = match.group(1).lower()
        if not (scheme in SCHEMES or (scheme == "file" and allow_file)):
            return f"scheme {scheme!r} is not allowed (allowed: {schemes})"
        # ssh://-oProxyCommand=... : git hands the host to ssh, which reads it as an option
        authority = url[match.end() :].split("/", 1)[0]
        if any(part.startswith("-") for part in re.split(r"[@:]", authority)):
            return "a repository URL's user, host or port must not start with '-'"
        try:
            urlsplit(url).port  # noqa: B018 (read for its check: an unclosed '[', a port of letters)
        except ValueError as error:
            return f"not a URL git can read: {error}"
        if "@" in authority and (scheme != "ssh" or ":" in authority.rsplit("@", 1)[0]):
            return (  # the URL is shown on pages and in the API, and put on git's command line
                "a repository URL must not carry a password or token (https://user:token@...): "
                "give the performance hosts theirs with git's credential helper or an ssh key"
            )
        return None
    if url.startswith("/"):
        return (
            None
            if allow_file
            else (
                f"a local repository (a path or file:// URL) is not allowed (allowed: {schemes}; "
                "a server or agent "
                "allows local paths with REDLINE_ALLOW_FILE_REPOS=true)"
            )
        )
    if _SCP_LIKE.match(url):
        return None
    return f"{url!r} is neither a URL nor an absolute path (allowed: {schemes})"


def _git(*args: str, cwd: Path | None = None) -> str:
    env = {**os.environ, "GIT_TERMINAL_PROMPT": "0"}  # a missing credential fails, never waits
    done = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        detail = done.stderr.strip() or done.stdout.strip()
        raise CheckoutError(f"git {' '.join(args)} failed: {detail}")
    return done.stdout


def _fetched(mirror: Path) -> tuple[str, ...]:
    """The refspecs a mirror fetches (none set: git exits 1, and so it fetches none)."""
    try:
        return tuple(_git("config", "--get-all", "remote.origin.fetch", cwd=mirror).split())
    except CheckoutError:
        return ()


class CloneCache:
    def __init__(self, root: Path, allow_file: bool = False) -> None:
        self.root = root
        self.allow_file = allow_file
        (root / "mirrors").mkdir(parents=True, exist_ok=True)
        (root / "trees").mkdir(parents=True, exist_ok=True)

    def _protocols(self) -> list[str]:
        """git's own guard on every transport it uses to fetch, submodules included."""
        allowed = (*SCHEMES, "file") if self.allow_file else SCHEMES
        return [
            "-c",
            "protocol.allow=never",
            *(part for scheme in allowed for part in ("-c", f"protocol.{scheme}.allow=always")),
        ]

    def mirror_path(self, repo: str) -> Path:
        return self.root / "mirrors" / hashlib.sha256(repo.encode()).hexdigest()[:16]

    def mirror(self, repo: str) -> Path:
        """Clone ``repo``'s branches and tags once (`REFSPECS`); fetch on later uses."""
        reason = refused_repo(repo, self.allow_file)
        if reason is not None:
            raise CheckoutError(f"repository {repo!r} refused: {reason}")
        path = self.mirror_path(repo)
        if path.exists() and _fetched(path) != REFSPECS:
            shutil.rmtree(path)  # an older agent's mirror of every ref: made again
        if not path.exists():
            # a bare clone takes branches and tags only, and sets no refspec to fetch later
            _git(*self._protocols(), "clone", "--quiet", "--bare", "--", repo, str(path))
            for refspec in REFSPECS:
                _git("config", "--add", "remote.origin.fetch", refspec, cwd=path)
        _git(*self._protocols(), "fetch", "--quiet", "--prune", "origin", cwd=path)
        return path

    def checkout(self, repo: str, commit: str, name: str) -> Path:
        """A fresh work tree of ``repo`` at ``commit`` under ``trees/name``."""
        if not commit or commit.startswith("-"):
            raise CheckoutError(
                f"commit {commit!r} refused: it must name a revision and must not start with '-'"
            )
        mirror = self.mirror(repo)
        tree = self.tree(name)
        shutil.rmtree(tree, ignore_errors=True)
        _git("clone", "--quiet", "--shared", "--no-checkout", "--", str(mirror), str(tree))
        try:
            sha = _git(
                "rev-parse",
                "--verify",
                "--quiet",
                "--end-of-options",
                f"{commit}^{{commit}}",
                cwd=tree,
            ).strip()
        except CheckoutError:
            sha = ""
        if sha and COMMIT_HASH.fullmatch(commit) and not sha.startswith(commit.lower()):
            # a tag named like a hash, or an annotated tag's own hash: the server takes a ci
            # token's commit by its hash only, and knows one commit under two names by it
            raise CheckoutError(
                f"commit {commit!r} names commit {sha[:12]} (a tag of that name, or a tag's "
                "own hash): a revision names a commit by the commit's own hash"
            )
        # objects can be there without a branch or tag holding them (a local clone copies
        # every object, a branch may have been rewritten): only what those refs reach is built
        if not sha or not _git(*REACHED_FROM, sha, "refs/remotes", "refs/tags", cwd=tree).strip():
            raise CheckoutError(  # a trial's mistyped commit was told only of pull requests
                f"commit {commit!r} is not on a branch or tag of {repo}: mistyped, not pushed "
                "yet, or a pull or merge request's (not built until it is pushed to a branch)"
            )
        _git("-c", "advice.detachedHead=false", "checkout", "--quiet", "--detach", sha, cwd=tree)
        return tree

    @staticmethod
    def head(tree: Path) -> str:
        """The hash of the commit checked out in ``tree``: what a run of it measured, whatever
        name (a branch, a tag) the revision gave."""
        return _git("rev-parse", "--verify", "HEAD", cwd=tree).strip()

    def tree(self, name: str) -> Path:
        """Where the work tree ``name`` is checked out."""
        return self.root / "trees" / name

    def discard(self, name: str) -> None:
        shutil.rmtree(self.tree(name), ignore_errors=True)
