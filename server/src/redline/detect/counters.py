"""What Redline knows of a series by its name: its kind, which way is worse, whether a verdict is
asked of it.

- **counter**: a component process's counter from the monitor (CPU, memory, threads...): a
  higher value is worse.
- **driver**: a metric the test driver measured of the component (`redline.recording.driver`):
  round trips and lateness are worse higher, achieved rates worse lower, timeouts and losses
  worse higher and judged as counts; the load it delivered (queries sent...) is not judged.
- **host**, **redline** and **recorder**: the machine's context (what else used it), Redline's own
  processes' CPU, and the recorder's own counts, charted; of the recorder's, only its losses
  are judged.

Some counters move without the code changing: two runs of one commit moved ``cpu_system_percent``
by +27 % and ``cpu_user_percent`` by -26 % while ``cpu_percent`` (their sum) moved -3.8 %
(issue 11). The split is recorded and charted; by default only the total is judged, and a
component judges the split when it asks (its detection configuration's ``context_counters``;
`redline compare --judge-split`).
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping
from typing import Protocol, TypeVar

from redline.recording import HOST_PROCESS
from redline.recording.driver import (
    CPU_PER_OP,
    CPU_REFS_PER_OP,
    DRIVER_PROCESS,
    RECORDER_PROCESS,
    Metric,
    metric_of,
)
from redline.recording.format import OWN_PROCESS

#: Counters recorded and charted but, unless a component asks, not judged: the user/system split
#: of CPU (above); involuntary context switches, which the scheduler makes when other
#: processes want the CPU: they follow the host's load more than the code (flagged 4 times in
#: `bench_verdicts`' 54 revisions, each dropped by its re-runs as noise; a trial's README commit
#: flagged at +92 % against a baseline whose own executions ranged 343-801 a second); and the
#: CPU time per unit of work, judged in units of the host's reference work instead
#: (``cpu_refs_per_op``: its spread between executions of the same code was 2.5-6.8 % where the
#: CPU time's was 6.1-13.1 %, docs/detection.md). A component whose recordings carry no
#: reference (made by an older agent) asks for ``cpu_us_per_op`` by leaving it out of its list.
CONTEXT_COUNTERS: tuple[str, ...] = (
    "cpu_user_percent",
    "cpu_system_percent",
    "ctx_involuntary_per_s",
    CPU_PER_OP,
)


#: The counters of what a process holds or has done since it started (memory, bytes read and
#: written so far, threads, processes, open files): their value at a parameter set depends on
#: every set that ran before it in the run (a leak grows over the run). What it does per unit of
#: time or work (CPU, context switches, CPU per operation, a round trip) does not, once the
#: set's warm-up has run: a confirmation run of such a change runs the flagged sets alone.
CUMULATIVE: tuple[str, ...] = ("_bytes", "threads", "processes", "fds")


def is_cumulative(counter: str) -> bool:
    """Whether ``counter`` accumulates over a process's life (`CUMULATIVE`)."""
    return counter.endswith(CUMULATIVE)


#: What a process holds that other load does not move: its memory, processes and open files,
#: judged in a phase the host was busy in too. In `bench_verdicts`' loaded part (2026-12-05), 16
#: phases measured while the host was busy held memory within 1.2 % of the quiet phases' median
#: (139 quiet ones: within 1.1 %). (Bytes read and written are cumulative too, but follow the
#: work done, which a busy host slows.)
HELD: tuple[str, ...] = (
    "rss_bytes",
    "uss_bytes",
    "pss_bytes",
    "processes",
    "fds",
)

#: What a process holds that other load can move: its threads and its address space. A run at
#: 44cae40 (2026-12-06, docs/detection.md "Again at 44cae40") had a thread more and 75.5 MB
#: more address space (a thread's stack and a malloc arena) in runs with busy phases: a false
#: regression, which confirmation pairs measured while the host was busy confirmed. They are
#: judged only in a phase the host was not busy in, as the CPU is, so such pairs run again.
#: (The thread stayed for the rest of its run, into a phase that was not busy: such a phase is
#: still judged, and its pairs decide.)
LOAD_HELD: tuple[str, ...] = ("threads", "vms_bytes")


def left_out(keys: Iterable[S], disturbed: Mapping[tuple[str, str, str], str]) -> dict[S, str]:
    """Of a run's series (``keys``: case, phase, params, process, counter), those not to judge,
    each with why, given its disturbed segments (case, phase, params → why): a busy segment's
    series but what the component holds and other load does not move (`HELD`)."""
    return {
        key: disturbed[(key.case, key.phase, key.params)]
        for key in keys
        if (key.case, key.phase, key.params) in disturbed and not is_held(key.process, key.counter)
    }


def is_held(process: str, counter: str) -> bool:
    """Whether the series is of what a component's process holds and other load does not move
    (`HELD`): judged even in a phase the host was busy in."""
    return kind(process) == "counter" and counter in HELD


def holds(process: str, counter: str) -> bool:
    """Whether the series is of what a component's process holds (`HELD` and `LOAD_HELD`): it
    barely moves from run to run."""
    return kind(process) == "counter" and counter in (*HELD, *LOAD_HELD)


def kind(process: str) -> str:
    """``counter``, ``driver``, ``host``, ``redline`` or ``recorder``."""
    if process == HOST_PROCESS:
        return "host"
    if process == OWN_PROCESS:
        return "redline"
    if process in (DRIVER_PROCESS, RECORDER_PROCESS):
        return process
    return "counter"


def driver_metric(process: str, counter: str) -> Metric | None:
    """The driver's (or recorder's) metric a series measures; None for any other series."""
    return metric_of(counter) if process in (DRIVER_PROCESS, RECORDER_PROCESS) else None


def worse(process: str, counter: str) -> str:
    """The direction of a change for the worse: ``increase`` (a higher value of the series is
    worse) or ``decrease`` (a lower one is, as for an achieved rate)."""
    metric = driver_metric(process, counter)
    return metric.worse if metric is not None else "increase"


def is_count(process: str, counter: str) -> bool:
    """Whether the series counts rare events (timeouts, losses), judged as a rate."""
    metric = driver_metric(process, counter)
    return metric is not None and metric.is_count


def is_load(process: str, counter: str) -> bool:
    """Whether the series is a load the driver delivered (queries sent...), not a measurement."""
    return kind(process) in ("driver", "recorder") and metric_of(counter) is None


#: A driver's extremes (the largest and the 99th percentile of a phase's few hundred round trips
#: or lateness samples): one outlier decides them, so they are charted, not judged.
EXTREMES = ("_max_us", "_p99_us")
#: The driver's lateness (how late its fixed-rate loop fired): the harness's own timing, charted,
#: not judged. It follows the host's load and the component's round trip, both judged, and near
#: the rate at which the round trip saturates the loop it grows a thousandfold for a few per cent
#: of round trip: `bench_verdicts` flagged unchanged revisions by it in most runs, and on
#: 2026-12-07 both pairs confirmed one (+14,526 %, its round trip 15 % slower in every run).
LATENESS = "lateness_"


#: A component's CPU share: where the host's speed is recorded, methods judging executions judge
#: it per unit of work at that speed instead (`one_cpu_figure`)
SHARE = "cpu_percent"


class Named(Protocol):
    """A series by its names: a `SeriesKey`, or the server's stored series."""

    @property
    def case(self) -> str: ...
    @property
    def phase(self) -> str: ...
    @property
    def params(self) -> str: ...
    @property
    def process(self) -> str: ...
    @property
    def counter(self) -> str: ...


S = TypeVar("S", bound=Named)


#: the levels a method judges a series' values at (`redline.detect.methods.Detector.level`)
LEVELS = ("sample", "execution", "build")


def figure(process: str, counter: str) -> tuple[str, str]:
    """The measurement a series is a figure of: a process's CPU share and its CPU per unit of
    work at the host's speed are one (`one_cpu_figure`), every other counter its own."""
    return process, SHARE if counter == CPU_REFS_PER_OP else counter


def one_cpu_figure(series: Iterable[S], levels: Collection[str] = LEVELS) -> list[S]:
    """``series`` (judged ones) less the CPU figure that methods judging at ``levels`` do not
    ask of: a component's CPU share and its CPU per unit of work at the host's speed
    (`CPU_REFS_PER_OP`, recorded where the driver's work and the host's reference were) are
    the same figure with the driver's load fixed, the share with the host's speed in it, and
    judging both would ask twice of one measurement. A method judging one value per execution
    or per build judges the figure per unit of work; one judging samples pooled (KS) judges the
    share, whose samples it needs: the per-unit figure is one value an execution, and one
    execution a revision would leave it nothing to judge. Both stay where methods of either
    kind ask."""
    listed = list(series)

    def segment(s: S) -> tuple[str, str, str, str]:
        return s.case, s.phase, s.params, s.process

    shares = {segment(s) for s in listed if s.counter == SHARE}
    both = {segment(s) for s in listed if s.counter == CPU_REFS_PER_OP} & shares
    asked = {SHARE: "sample" in levels, CPU_REFS_PER_OP: any(lv != "sample" for lv in levels)}
    return [s for s in listed if segment(s) not in both or asked.get(s.counter, True)]


def judged_among(
    series: Iterable[S],
    context: Collection[str] = CONTEXT_COUNTERS,
    levels: Collection[str] = ("execution",),
) -> list[S]:
    """The series a verdict is asked of among one run's or one revision's (`judged`) by
    methods judging at ``levels``: of a CPU share beside its CPU per unit of work at the host's
    speed, one (`one_cpu_figure`)."""
    return one_cpu_figure((s for s in series if judged(s.process, s.counter, context)), levels)


def judged(process: str, counter: str, context: Collection[str] = CONTEXT_COUNTERS) -> bool:
    """Whether a verdict is asked of this series: not the host's, not a context counter, not a
    load the driver delivered, not a driver's extreme (`EXTREMES`) nor its lateness
    (`LATENESS`)."""
    series_kind = kind(process)
    if series_kind in ("driver", "recorder"):
        field = counter.rpartition(":")[2]
        return (
            metric_of(counter) is not None
            and not counter.endswith(EXTREMES)
            and not field.startswith(LATENESS)
        )
    return series_kind == "counter" and counter not in context
