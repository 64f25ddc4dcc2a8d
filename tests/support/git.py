"""Real local git repositories for checkout and agent tests."""

from __future__ import annotations

import subprocess
from pathlib import Path

GIT = ["git", "-c", "user.name=t", "-c", "user.email=t@t.invalid"]


def committed_repo(repo: Path, files: dict[str, str]) -> tuple[Path, str]:
    """A repository at ``repo`` whose one commit holds ``files`` (path -> text); and its hash."""
    for name, text in files.items():
        (repo / name).parent.mkdir(parents=True, exist_ok=True)
        (repo / name).write_text(text)
    subprocess.run([*GIT, "init", "-q", "-b", "main"], cwd=repo, check=True)
    subprocess.run([*GIT, "add", "-A"], cwd=repo, check=True)
    subprocess.run([*GIT, "commit", "-qm", "one"], cwd=repo, check=True)
    head = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=repo, check=True, capture_output=True, text=True
    ).stdout.strip()
    return repo, head


def empty_commits(repo: Path, count: int) -> list[str]:
    """``count`` commits on top of ``repo``'s head that change nothing: the same code under
    distinct hashes (one commit reported under two titles is one revision); their hashes."""
    hashes = []
    for number in range(count):
        subprocess.run(
            [*GIT, "commit", "-q", "--allow-empty", "-m", f"again {number}"], cwd=repo, check=True
        )
        hashes.append(
            subprocess.run(
                ["git", "rev-parse", "HEAD"], cwd=repo, check=True, capture_output=True, text=True
            ).stdout.strip()
        )
    return hashes
