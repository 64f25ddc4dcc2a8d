"""The agent's spool: finished recordings waiting for the server, kept on disk until accepted.

A recording enters the spool as ``<work>/spool/job-<id>.mcap`` (one atomic rename, so the file name
carries the job id and nothing else needs writing) before its first upload attempt, and leaves it
only when the server has accepted it — or refused it for good, in which case it is kept under
``spool/rejected/`` for a person to look at. A background sender retries with backoff, and a
restarted agent picks up whatever an earlier one left.
"""

from __future__ import annotations

import logging
import os
import re
import threading
from dataclasses import dataclass
from pathlib import Path

from redline.agent.client import ServerClient, ServerUnavailable, UploadRejected

log = logging.getLogger("redline.agent.spool")

_NAME = re.compile(r"^job-(\d+)\.mcap$")


@dataclass(frozen=True)
class Spooled:
    job_id: int
    path: Path


class Spool:
    def __init__(self, root: Path) -> None:
        self.root = root
        (root / "rejected").mkdir(parents=True, exist_ok=True)
        #: held while a recording is being sent, so the foreground and the sender never race
        self.lock = threading.Lock()

    def put(self, job_id: int, recording: Path) -> Spooled:
        """Move a finished recording into the spool (same file system: an atomic rename)."""
        path = self.root / f"job-{job_id}.mcap"
        os.replace(recording, path)
        return Spooled(job_id, path)

    def holds(self, job_id: int) -> bool:
        return (self.root / f"job-{job_id}.mcap").exists()

    def pending(self) -> list[Spooled]:
        """What still waits for the server, oldest job first."""
        found = [
            (int(m.group(1)), p)
            for p in self.root.iterdir()
            if p.is_file() and (m := _NAME.match(p.name))
        ]
        return [Spooled(job_id, path) for job_id, path in sorted(found)]

    def send(
        self, client: ServerClient, entry: Spooled, *, attempts: int = 1, backoff: float = 1.0
    ) -> int | None:
        """Upload one entry; its execution id once accepted (and removed), None if refused.

        Raises ServerUnavailable (the entry stays) when the server cannot take it now.
        """
        with self.lock:
            if not entry.path.exists():  # sent meanwhile by the other side
                return None
            try:
                execution = client.upload(
                    entry.job_id, entry.path, attempts=attempts, backoff=backoff
                )
            except UploadRejected:
                os.replace(entry.path, self.root / "rejected" / entry.path.name)
                raise
            entry.path.unlink(missing_ok=True)
            return execution


class SpoolSender:
    """Retries the spool in the background until every recording is accepted."""

    def __init__(
        self,
        spool: Spool,
        client: ServerClient,
        stop: threading.Event,
        *,
        min_delay: float = 1.0,
        max_delay: float = 60.0,
    ) -> None:
        self.spool, self.client, self.stop = spool, client, stop
        self.min_delay, self.max_delay = min_delay, max_delay
        self.wake = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="spool-sender", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _loop(self) -> None:
        delay = self.min_delay
        while not self.stop.is_set():
            delay = self.min_delay if self.send_all() else min(delay * 2, self.max_delay)
            self.wake.wait(delay)
            self.wake.clear()

    def send_all(self) -> bool:
        """Try every spooled recording once; False when the server could not take one."""
        for entry in self.spool.pending():
            try:
                execution = self.spool.send(self.client, entry)
            except UploadRejected as exc:
                log.error("spooled job %s refused, kept in spool/rejected: %s", entry.job_id, exc)
            except ServerUnavailable as exc:
                log.warning(
                    "server unavailable, %d recording(s) stay spooled: %s",
                    len(self.spool.pending()),
                    exc,
                )
                return False
            except Exception:  # never let the sender die: the spool is the agent's memory
                log.exception("sending spooled job %s failed", entry.job_id)
                return False
            else:
                if execution is not None:
                    log.info("spooled job %s: uploaded as execution %s", entry.job_id, execution)
        return True
