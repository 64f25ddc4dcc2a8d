"""A cache of clones on the performance host: one mirror per repository, one work tree per job."""

from __future__ import annotations

import hashlib
import shutil
import subprocess
from pathlib import Path


class CheckoutError(RuntimeError):
    """git could not produce the requested revision; the message carries git's own words."""


def _git(*args: str, cwd: Path | None = None) -> str:
    done = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        detail = done.stderr.strip() or done.stdout.strip()
        raise CheckoutError(f"git {' '.join(args)} failed: {detail}")
    return done.stdout


class CloneCache:
    def __init__(self, root: Path) -> None:
        self.root = root
        (root / "mirrors").mkdir(parents=True, exist_ok=True)
        (root / "trees").mkdir(parents=True, exist_ok=True)

    def mirror(self, repo: str) -> Path:
        """Clone ``repo`` once as a bare mirror; fetch on later uses."""
        path = self.root / "mirrors" / hashlib.sha256(repo.encode()).hexdigest()[:16]
        if path.exists():
            _git("fetch", "--quiet", "--prune", "origin", cwd=path)
        else:
            _git("clone", "--quiet", "--mirror", repo, str(path))
        return path

    def checkout(self, repo: str, commit: str, name: str) -> Path:
        """A fresh work tree of ``repo`` at ``commit`` under ``trees/name``."""
        mirror = self.mirror(repo)
        tree = self.root / "trees" / name
        shutil.rmtree(tree, ignore_errors=True)
        _git("clone", "--quiet", "--shared", "--no-checkout", str(mirror), str(tree))
        _git("-c", "advice.detachedHead=false", "checkout", "--quiet", commit, cwd=tree)
        return tree

    def discard(self, name: str) -> None:
        shutil.rmtree(self.root / "trees" / name, ignore_errors=True)
