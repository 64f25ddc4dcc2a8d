"""Was the host quiet? What else used it during each phase, and when a phase counts as disturbed.

A verdict is only as good as the measurement under it: another job on a performance host moved
an unchanged component's CPU by 13 to 27 % (issue 11). For every segment the reader derives the
host series `OTHER_CPU`: the host's busy and stolen CPU (% of all CPUs, times the cores) minus
what the run's own processes used (the components, and Redline's runner, recorder and monitor,
process ``redline``), in % of one core; and `OTHER_PEAK`, the same over each whole second of
the segment, in its busiest tenth of them. A segment whose other load,
or that, exceeds the threshold (`threshold`: ``REDLINE_DISTURBED_CPU_PERCENT``, default
`DEFAULT_THRESHOLD`, chosen from the measurements in docs/detection.md) is disturbed: its series
get the verdict "not enough data (host busy ...)", the agent runs the execution again
(boundedly), and `redline run` and `redline compare` say so.
"""

from __future__ import annotations

import os
from bisect import bisect_right
from collections.abc import Mapping, Sequence
from statistics import quantiles
from typing import Any

from redline.recording.format import HOST_PROCESS, OWN_PROCESS

#: The host series of what else used the host during a segment, in % of one core.
OTHER_CPU = "other_cpu_percent"
#: ... and in the busiest tenth of its whole seconds (their 90th percentile):
#: a load that came and went within a phase moved the component's CPU in it while the phase's
#: mean stayed under the threshold (the benchmark's load, a core switched on and off every 3-30
#: s, over 4-s phases); a tenth, so that one busy second in a phase of minutes does not disturb
#: it all
OTHER_PEAK = "other_cpu_p90_percent"
#: the share of a phase's seconds that `OTHER_PEAK` reaches beyond
PEAK_SHARE = 0.1
#: Other load, in % of one core, above which a phase is disturbed (docs/detection.md).
DEFAULT_THRESHOLD = 30.0
THRESHOLD_VARIABLE = "REDLINE_DISTURBED_CPU_PERCENT"

SECOND_NS = 1_000_000_000
#: the host's CPU is a rate over a window ending at its sample of half a second or a tick more
#: (`WindowRate`, at the monitor's 10 Hz)
HOST_WINDOW_NS = 500_000_000
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


def other_peak(
    samples: Sequence[Mapping[str, Any]], begin_ns: int, end_ns: int, cores: int
) -> float | None:
    """What else used the host in the busiest `PEAK_SHARE` of the whole seconds of the phase
    from ``begin_ns`` to ``end_ns`` (the 90th percentile of each second's other load), from the
    monitor's ``samples`` in time order. The host's CPU is a rate over its last `HOST_WINDOW_NS`
    or so, the processes' over their last tick: at each host sample, the processes' ticks in its
    window are taken off it, so that a heavier phase before, or a component whose CPU jumps from
    tick to tick, is no one else's load (a sample whose window began before the phase is left
    out); a second's other load is the mean of its host samples'. None where it cannot be told."""
    host: list[tuple[int, float]] = []
    used: dict[str, tuple[list[int], list[float]]] = {}
    for sample in samples:
        values, t_ns = sample["values"], sample["t_ns"]
        cpu = values.get("cpu_percent")
        if cpu is None:
            continue
        if sample["process"] == HOST_PROCESS:
            if t_ns - HOST_WINDOW_NS >= begin_ns:
                host.append((t_ns, float(cpu) + float(values.get("cpu_steal_percent") or 0.0)))
        else:
            times, cpus = used.setdefault(sample["process"], ([], []))
            times.append(t_ns)
            cpus.append(float(cpu))
    if not host or OWN_PROCESS not in used or cores <= 0:
        return None
    by_second: dict[int, list[float]] = {}
    for t_ns, busy in host:
        second = (t_ns - begin_ns - 1) // SECOND_NS  # (begin + k s, begin + (k + 1) s]
        if begin_ns + (second + 1) * SECOND_NS > end_ns:
            continue  # whole seconds only
        total = 0.0
        for times, cpus in used.values():
            lo, hi = bisect_right(times, t_ns - HOST_WINDOW_NS), bisect_right(times, t_ns)
            total += sum(cpus[lo:hi]) / (hi - lo) if hi > lo else 0.0
        by_second.setdefault(second, []).append(busy * cores - total)
    seconds = [max(0.0, sum(others) / len(others)) for others in by_second.values()]
    if len(seconds) < 2:
        return round(seconds[0], 3) if seconds else None
    return round(quantiles(seconds, n=round(1 / PEAK_SHARE), method="inclusive")[-1], 3)


def disturbed(
    others: Mapping[Segment, Sequence[float]],
    limit: float,
    peaks: Mapping[Segment, Sequence[float]] | None = None,
) -> dict[Segment, str]:
    """The disturbed segments, each with the reason its verdicts give, from each segment's
    other load (the `OTHER_CPU` values of its executions) and that of its busiest tenth of
    seconds (`OTHER_PEAK`): disturbed when any is over."""
    found = {}
    for segment in dict.fromkeys([*others, *(peaks or {})]):
        worst = max(others.get(segment, ()), default=0.0)
        peak = max((peaks or {}).get(segment, ()), default=0.0)
        if worst > limit:
            found[segment] = (
                f"{BUSY} other load {_over(worst, limit)} % of a core during the phase "
                f"(over {limit:g} %)"
            )
        elif peak > limit:
            found[segment] = (
                f"{BUSY} other load {_over(peak, limit)} % of a core in the busiest tenth of the "
                f"phase's seconds (over {limit:g} %)"
            )
    return found


def _over(value: float, limit: float) -> str:
    """``value`` (over ``limit``) as a whole number, or with the decimals that keep it over the
    limit ("30 % ... (over 30 %)" read as a contradiction)."""
    for digits in range(3):
        if round(value, digits) > limit:
            return f"{value:.{digits}f}"
    return f"{value:.3f}"


def recording_disturbances(
    samples: Mapping[Any, Sequence[float]], limit: float
) -> dict[Segment, str]:
    """The disturbed segments of one recording's samples (`Recording.series_samples`)."""

    def of(counter: str) -> dict[Segment, Sequence[float]]:
        return {
            (key.case, key.phase, key.params): values
            for key, values in samples.items()
            if key.process == HOST_PROCESS and key.counter == counter
        }

    return disturbed(of(OTHER_CPU), limit, of(OTHER_PEAK))
