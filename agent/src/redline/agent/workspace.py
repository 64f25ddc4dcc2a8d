"""Where a run keeps its files: a workspace folder for the run's own files, and the processes'
logs in a folder beside the recording.

The workspace (``redline-<suite>-XXXX``: the run metadata the recorder reads, the components'
zenoh configuration) is made in the work folder: the ``work_dir`` given, else ``$REDLINE_WORK_DIR``,
else the system's temporary folder. It is removed after every run, failed or not, unless kept.
Every process logs to ``<recording without suffix>.logs/<process>.log`` beside the recording, so
that the logs of a failed run stay where the user looks for its recording and the paths in its
error message stay true; after a run that went well they are removed unless kept.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

WORK_DIR_VARIABLE = "REDLINE_WORK_DIR"


def work_folder(given: str | Path | None = None) -> Path | None:
    """The folder workspaces go in: ``given``, else ``$REDLINE_WORK_DIR``; None means the
    system's temporary folder."""
    chosen = given or os.environ.get(WORK_DIR_VARIABLE)
    return Path(chosen).resolve() if chosen else None


def new_workspace(suite_name: str, work_dir: str | Path | None = None) -> Path:
    folder = work_folder(work_dir)
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f"redline-{suite_name}-", dir=folder))


def logs_folder(recording: Path) -> Path:
    """``run.mcap`` → ``run.logs``: where the processes of the run writing it log."""
    return recording.with_suffix(".logs")


def fresh_logs(recording: Path) -> Path:
    """The recording's log folder, without the logs of an earlier run to mislead."""
    folder = logs_folder(recording)
    if folder.is_dir():
        _remove_logs(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _remove_logs(folder: Path) -> None:
    """The ``*.log`` files Redline writes, and the folder if that empties it (a file of the
    user's own in it is left alone)."""
    for log in folder.glob("*.log"):
        log.unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        folder.rmdir()


def tidy(
    workspace: Path, logs: Path, *, succeeded: bool, keep: bool, say: Callable[[str], None]
) -> tuple[Path | None, Path | None]:
    """Remove the workspace unless kept, and the logs unless kept or the run failed; return
    what is left (workspace, logs)."""
    if keep:
        say(f"workspace kept: {workspace}")
    else:
        shutil.rmtree(workspace, ignore_errors=True)
    if keep or not succeeded:
        say(f"logs of every process: {logs}")
    else:
        _remove_logs(logs)
    return (workspace if keep else None), (logs if keep or not succeeded else None)
