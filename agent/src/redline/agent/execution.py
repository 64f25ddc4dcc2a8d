"""Running the test cases: every case, phase and parameter set in order, between markers."""

from __future__ import annotations

import json
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

import zenoh
from redline.agent.processes import RunError
from redline.recording.format import MARKERS_KEY
from redline.testing import Context, Link, ParameterSet, Phase, TestCase


class Markers:
    """Publishes begin/end markers on ``@redline/markers`` (format in recording/format.py)."""

    def __init__(
        self, session: zenoh.Session, hold: Callable[[], AbstractContextManager[Any]] = nullcontext
    ) -> None:
        """``hold``: a section no signal may cut (`SignalGuard.held`): a put a signal cut in
        half left an empty marker, and the whole recording unreadable (seen under load)."""
        # Markers are rare and a lost one loses a whole segment, so this publisher may block.
        self._publisher = session.declare_publisher(
            MARKERS_KEY, congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._hold = hold
        self._open: tuple[str, Phase, dict[str, Any]] | None = None

    def publish(self, event: str, case: str, phase: Phase, params: dict[str, Any]) -> None:
        if event == "begin":
            self._open = (case, phase, params)
        payload = json.dumps(
            {
                "t_ns": time.time_ns(),
                "event": event,
                "case": case,
                "phase": phase.name,
                "params": params,
                "warmup": phase.warmup,
            },
            default=str,
        )
        with self._hold():
            self._publisher.put(payload)
        if event == "end":
            self._open = None

    def close(self) -> None:
        """End a segment that a signal cut short between its markers, then undeclare.

        The reader ignores an end without its begin, so an end sent twice or for a begin that
        never went out is harmless; a begin without its end would lose the segment.
        """
        if self._open is not None:
            self.publish("end", *self._open)
        self._publisher.undeclare()


#: Redline's own package (the agent's part of it, the SDK's actions included): frames in it
#: are not where a test's error is
OWN = Path(__file__).resolve().parents[1]


def raised_at(exc: BaseException) -> str:
    """Where in the test's own code ``exc`` was raised: the innermost frame of its traceback
    outside Redline's package (a trial's raising action said only "RuntimeError: boom"); ""
    when every frame is Redline's."""
    frames = [
        frame
        for frame in traceback.extract_tb(exc.__traceback__)
        if not Path(frame.filename).resolve().is_relative_to(OWN)
    ]
    if not frames:
        return ""
    return f" (raised at {frames[-1].filename}:{frames[-1].lineno}, in {frames[-1].name})"


#: Called with each segment's phase and the driver reports it published (`TrafficCheck`).
Observer = Callable[[Phase, list[dict[str, Any]]], None]


def _run_segment(
    case: TestCase,
    phase: Phase,
    params: ParameterSet,
    link: Link,
    markers: Markers,
    stop: threading.Event,
    observe: Observer | None,
) -> None:
    ctx = Context(params, case.name, phase.name, link, stop, paths=phase.paths)
    markers.publish("begin", case.name, phase, params)
    try:
        phase.action.run(ctx)
    except Exception as exc:
        raise RunError(
            f"test case {case.name!r}, phase {phase.name!r} [{params.name}]: "
            f"{type(exc).__name__}: {exc}{raised_at(exc)}"
        ) from exc
    finally:
        ctx.flush_metrics()  # query round trips, waits: one summary per action and key
        markers.publish("end", case.name, phase, params)
        if observe is not None:
            observe(phase, ctx.reports)


def execute_cases(
    cases: Sequence[TestCase],
    link: Link,
    markers: Markers,
    stop: threading.Event,
    say: Callable[[str], None],
    observe: Observer | None = None,
) -> int:
    """Run every case → parameter set → phase until done or ``stop``; returns segments run.

    For each parameter set the case's phases run in order, so a warm-up phase warms up the load
    that its steady phase then measures, and phases can form a protocol (the paper's
    "transactions"); the component keeps running throughout.
    """
    done = 0
    for case in cases:
        for params in case.parameter_sets():
            for phase in case.phases:
                if stop.is_set():
                    return done
                label = " (warm-up)" if phase.warmup else ""
                say(f"{case.name}/{phase.name} [{params.name}]{label}")
                _run_segment(case, phase, params, link, markers, stop, observe)
                done += 1
    return done
