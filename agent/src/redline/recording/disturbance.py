"""Was the host quiet? What else used it during each phase, and when a phase counts as disturbed.

A verdict is only as good as the measurement under it: another job on a performance host moved
an unchanged component's CPU by 13 to 27 % (issue 11). For every segment the reader derives the
host series `OTHER_CPU`: the host's busy and stolen CPU (% of all CPUs, times the cores) minus
what the run's own processes used (the components, and Redline's runner, recorder and monitor,
process ``redline``), in % of one core. A segment whose other load exceeds the threshold
(`threshold`: ``REDLINE_DISTURBED_CPU_PERCENT``, default `DEFAULT_THRESHOLD`, chosen from the
measurements in docs/detection.md) is disturbed: its series get the verdict "not enough data
(host busy ...)", the agent runs the execution again (boundedly), and `redline run` and `redline
compare` say so.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

from redline.recording.format import HOST_PROCESS, OWN_PROCESS

#: The host series of what else used the host during a segment, in % of one core.
OTHER_CPU = "other_cpu_percent"
#: Other load, in % of one core, above which a phase is disturbed (docs/detection.md).
DEFAULT_THRESHOLD = 30.0
THRESHOLD_VARIABLE = "REDLINE_DISTURBED_CPU_PERCENT"

Segment = tuple[str, str, str]  # case, phase, canonical parameters
#: what every disturbed segment's reason starts with, and a verdict it left undecided names
BUSY = "host busy:"


def names_busy_host(reason: str) -> bool:
    """Whether a "not enough data" reason is a busy host's (the candidate's or the baseline's
    runs disturbed), not a history too short or a run the component took no part in."""
    return BUSY in reason


def threshold() -> float:
    """The threshold in force: ``REDLINE_DISTURBED_CPU_PERCENT``, else the default."""
    given = os.environ.get(THRESHOLD_VARIABLE, "").strip()
    try:
        return float(given) if given else DEFAULT_THRESHOLD
    except ValueError:
        raise ValueError(
            f"{THRESHOLD_VARIABLE} must be a number (% of one core), not {given!r}"
        ) from None


def _mean(values: Sequence[Any]) -> float:
    numbers = [v[1] if isinstance(v, tuple) else v for v in values]
    return sum(numbers) / len(numbers)


def other_load(by_counter: Mapping[tuple[str, str], Sequence[Any]], cores: int) -> float | None:
    """What else used the host during one segment, in % of one core, from its samples grouped
    by (process, counter); None where it cannot be told (no host or no own samples)."""
    host = by_counter.get((HOST_PROCESS, "cpu_percent"))
    own = by_counter.get((OWN_PROCESS, "cpu_percent"))
    if not host or not own or cores <= 0:
        return None
    stolen = by_counter.get((HOST_PROCESS, "cpu_steal_percent")) or [0.0]
    used = sum(
        _mean(values)
        for (process, counter), values in by_counter.items()
        if counter == "cpu_percent" and process != HOST_PROCESS and values
    )
    return round(max(0.0, (_mean(host) + _mean(stolen)) * cores - used), 3)


def disturbed(others: Mapping[Segment, Sequence[float]], limit: float) -> dict[Segment, str]:
    """The disturbed segments, each with the reason its verdicts give, from each segment's
    other load (the `OTHER_CPU` values of its executions: disturbed when any is over)."""
    found = {}
    for segment, values in others.items():
        worst = max(values, default=0.0)
        if worst > limit:
            found[segment] = (
                f"{BUSY} other load {worst:.0f} % of a core during the phase (over {limit:g} %)"
            )
    return found


def recording_disturbances(
    samples: Mapping[Any, Sequence[float]], limit: float
) -> dict[Segment, str]:
    """The disturbed segments of one recording's samples (`Recording.series_samples`)."""
    return disturbed(
        {
            (key.case, key.phase, key.params): values
            for key, values in samples.items()
            if key.process == HOST_PROCESS and key.counter == OTHER_CPU
        },
        limit,
    )
