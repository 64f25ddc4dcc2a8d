"""Replay: publish what an MCAP recording holds, with its timing (the paper's BagAction)."""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping, Sequence
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from redline.recording.format import REDLINE_PREFIX
from redline.testing.actions import Action, resolve
from redline.testing.context import Context
from redline.testing.metrics import latency_summary
from redline.testing.middleware import key_problems

#: the folder of the test module being imported (`redline.agent.loader`): a `Replay` made there
#: finds a relative recording in it, wherever the run was started from, as the suite finds its
#: test modules beside it
LOADING_FROM: ContextVar[Path | None] = ContextVar("redline_loading_from", default=None)


@dataclass(frozen=True)
class Recorded:
    """One message to replay: its offset from the first, key, encoding and payload."""

    offset_ns: int
    key: str
    encoding: str
    data: bytes


def _messages(path: Path) -> Iterator[tuple[Channel, Message]]:
    channels: dict[int, Channel] = {}
    with open(path, "rb") as stream:  # the stream reader also reads a file cut off mid-way
        records = StreamReader(stream, skip_magic=False).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except Exception:  # noqa: BLE001 - a cut-off file: replay what came before the cut
                return
            if isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message) and record.channel_id in channels:
                yield channels[record.channel_id], record


def _remapped(key: str, remap: Mapping[str, str]) -> str:
    for old, new in remap.items():
        if key == old or key.startswith(old.rstrip("/") + "/"):
            return new + key[len(old) :]
    return key


def load_recorded(
    path: str | Path, keys: Sequence[str] | None = None, remap: Mapping[str, str] | None = None
) -> list[Recorded]:
    """The messages of a recording to replay, in log-time order, selected and remapped.

    Redline's own channels (``@redline/...``) are never replayed.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"Replay: no recording at {path}")
    selectors = [zenoh.KeyExpr(k) for k in keys] if keys else None
    found: list[tuple[int, str, str, bytes]] = []
    for channel, message in _messages(path):
        topic = channel.topic
        if topic.startswith(REDLINE_PREFIX):
            continue
        if selectors is not None and not any(s.intersects(zenoh.KeyExpr(topic)) for s in selectors):
            continue
        found.append(
            (
                message.log_time,
                _remapped(topic, remap or {}),
                channel.message_encoding,
                message.data,
            )
        )
    found.sort(key=lambda item: item[0])
    first = found[0][0] if found else 0
    return [Recorded(t - first, key, encoding, data) for t, key, encoding, data in found]


class Replay(Action):
    """Publish the samples of an MCAP recording on their keys, with their original spacing.

    ``recording`` is a path (or ``Param``), a relative one taken from the folder of the test
    module that made the action (else from the current folder); ``speed`` divides the gaps
    (2.0 = twice as fast); ``keys`` selects channels by key expression (``["robot/scan",
    "robot/odom/**"]``); ``remap`` renames key prefixes (``{"robot": "sim/robot"}``); ``loop``
    replays it again and again until interrupted (True) or that many times (a number). Redline's
    own channels are skipped. Reports messages sent and lateness percentiles; returns the number
    of messages sent.
    """

    def __init__(
        self,
        recording: str | Path | Action,
        *,
        speed: float | Action = 1.0,
        keys: Sequence[str] | None = None,
        remap: Mapping[str, str] | None = None,
        loop: bool | int = False,
    ) -> None:
        self.recording = recording
        self.speed = speed
        self.keys = list(keys) if keys else None
        self.remap = dict(remap or {})
        self.loop = loop
        self.folder = LOADING_FROM.get()
        self._loaded: dict[str, list[Recorded]] = {}

    def problems(self) -> list[str]:
        return key_problems("Replay keys", *(self.keys or [])) + key_problems(
            "Replay remap", *self.remap.values()
        )

    def missing(self) -> list[str]:
        if not isinstance(self.recording, str | Path):
            return []  # a `Param`'s is looked for when it runs
        lost = self._lost(self.recording)
        return [lost] if lost else []

    def path(self, recording: str | Path) -> Path:
        """Where ``recording`` is: a relative path in the folder of the module that made it, or
        in the current folder where only that has it (as a suite written before 2026-12-06
        found it, run from where its author ran it)."""
        given = Path(recording)
        if given.is_absolute() or self.folder is None:
            return given
        beside = self.folder / given
        return given if not beside.is_file() and given.is_file() else beside

    def _lost(self, recording: str | Path) -> str | None:
        """Why ``recording`` cannot be replayed: it is not where `path` looks; None: it is."""
        if self.path(recording).is_file():
            return None
        if Path(recording).is_absolute() or self.folder is None:
            return f"Replay: no recording at {recording}"
        return f"Replay: no recording at {recording} (in {self.folder}, the test module's folder)"

    def _load(self, recording: str) -> list[Recorded]:
        if recording not in self._loaded:
            lost = self._lost(recording)
            if lost:
                raise FileNotFoundError(lost)
            self._loaded[recording] = load_recorded(self.path(recording), self.keys, self.remap)
        return self._loaded[recording]

    def _passes(self) -> int | None:
        if self.loop is True:
            return None
        return max(1, int(self.loop))

    def run(self, ctx: Context) -> int:
        messages = self._load(str(resolve(self.recording, ctx)))
        speed = float(resolve(self.speed, ctx))
        if not speed > 0:
            raise ValueError(f"Replay speed must be positive, got {speed!r}")
        link = ctx.require_link()
        passes, done, sent, lateness = self._passes(), 0, 0, []
        while messages and (passes is None or done < passes) and not ctx.stopped:
            start = time.perf_counter_ns()
            for item in messages:
                deadline = start + int(item.offset_ns / speed)
                if not ctx.sleep_until(deadline):
                    break
                lateness.append(time.perf_counter_ns() - deadline)
                link.publisher(item.key, item.encoding or None).put(item.data)
                sent += 1
            done += 1
        ctx.report(self._summary(sent, done, lateness, ctx.stopped), action=self)
        return sent

    def _summary(
        self, sent: int, passes: int, lateness: list[int], interrupted: bool
    ) -> dict[str, Any]:
        return {
            "action": "Replay",
            "recording": str(self.recording),
            "messages": sent,
            "passes": passes,
            "interrupted": interrupted,
            **latency_summary(lateness, "lateness"),
        }
