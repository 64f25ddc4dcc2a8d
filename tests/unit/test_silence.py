"""A response the component stops sending while traffic still comes in: `Silence` alarms after
`HOLD` silent steps, ends after as many answered ones, and says nothing while nothing comes in;
`responses` learns which keys are answered at every step with incoming traffic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from redline.predict.dataset import NS, RESPONSE_MIN_STEPS, Run, responses
from redline.predict.watch import HOLD, Silence


def test_silence_alarms_after_hold_silent_steps_and_ends_after_as_many_answered_ones():
    silence = Silence("robot/persons")
    steps = [silence.update(30, 10) for _ in range(5)]  # answering: nothing to say
    assert steps == [None] * 5
    silent = [silence.update(30, 0) for _ in range(HOLD)]
    assert silent[:-1] == [None] * (HOLD - 1)
    alarm = silent[-1]
    assert alarm is not None and alarm.started and alarm.target == "silence:robot/persons"
    assert alarm.residual == 30 and alarm.step == 5 + HOLD
    assert [silence.update(0, 0) for _ in range(10)] == [None] * 10  # no traffic: no say
    assert silence.active
    back = [silence.update(30, 12) for _ in range(HOLD)]
    assert back[-1] is not None and not back[-1].started and not silence.active


def _run(sent_until_s: float | None, seconds: int = 30) -> Run:
    """30 legs a second for ``seconds``; persons answered each leg until ``sent_until_s``."""
    events = []
    for i in range(seconds * 30):
        t = NS + i * NS // 30
        events.append(("robot/legs", t, 64))
        if sent_until_s is None or t < NS + sent_until_s * NS:
            events.append(("robot/persons", t + 1000, 16))
        if i % 300 == 0:
            events.append(("robot/log", t + 2000, 8))  # now and then: no response
    return Run(Path("r.mcap"), events, {"robot/legs"}, [], {})


def _steps(seconds: int = 30) -> np.ndarray:
    return np.arange(2, seconds + 1, dtype=np.int64) * NS


def test_responses_are_the_keys_answered_at_every_step_with_incoming_traffic():
    assert responses([(_run(None), _steps())]) == ("robot/persons",)
    # one run in which the answers stopped for good: not a response any more
    assert responses([(_run(None), _steps()), (_run(10.0), _steps())]) == ()
    # too few steps with traffic to say
    assert RESPONSE_MIN_STEPS > 3
    assert responses([(_run(None), _steps()[:3])]) == ()
    # filtered out
    assert responses([(_run(None), _steps())], keys=lambda key: key != "robot/persons") == ()
