"""`redline watch` over a recording instead of a live component (``redline watch --replay``):
the same features, predictions, residuals and silences, step by step in the recording's time,
so a model can be checked against a run of any length in seconds — the five clean minutes a
model must watch without an alarm are a replay (tests/integration/test_watch_replay.py).

What the live watcher measures each second from /proc (CPU over the step, RSS) is here the mean
of the monitor's samples of the component's process over the step, the very values training
learnt from (`redline.predict.dataset`); what it heard, the recorder's arrival times. Steps run
each second from the first measured segment's start to the last one's end; until the longest
feature window is full they are warming, and judge nothing, as live. A step without a counter
sample of the process is left out. What else used the host in a step comes from the host's and
Redline's own samples, as live (`redline.predict.watch.Contention`).
"""

from __future__ import annotations

import numpy as np
from redline.predict.dataset import (
    RESPONSE_WINDOW_S,
    STEP_S,
    TARGETS,
    DataError,
    Run,
    component_process,
    in_window,
    step_targets,
)
from redline.predict.features import NS, extract
from redline.predict.model import ModelFile
from redline.predict.watch import (
    Alarm,
    Contention,
    Silence,
    Step,
    judge_step,
    other_cpu,
    trackers,
)
from redline.recording.disturbance import threshold
from redline.recording.format import HOST_PROCESS, OWN_PROCESS


def replay(model: ModelFile, run: Run) -> list[Step | Alarm]:
    """Every step of ``run`` watched with ``model``, each followed by the alarms it raised or
    ended, in order."""
    process = component_process([run], model.process)
    if not run.segments:
        raise DataError(f"{run.path}: no measured segment to replay")
    begin = min(segment.begin_ns for segment in run.segments)
    end = max(segment.end_ns for segment in run.segments)
    step = int(STEP_S * NS)
    times = np.arange(begin + step, end + 1, step, dtype=np.int64)
    measured = step_targets(run.samples[process], times)
    kept = ~np.isnan(measured["cpu_percent"])
    times, measured = times[kept], {t: values[kept] for t, values in measured.items()}
    if not len(times):
        raise DataError(f"{run.path}: no counter sample of process {process!r} to replay")
    others = _other_cpu(run, times)
    predicted = model.predict(extract(run.events, times, model.spec))
    known = model.spec.keys
    heard = np.array(sorted(stamp for key, stamp, _ in run.events if key in known), np.int64)
    answers = {
        key: np.array(sorted(stamp for k, stamp, _ in run.events if k == key), np.int64)
        for key in model.responses
    }
    received = in_window(heard, times, 1.0)
    answered = {key: in_window(stamps, times, RESPONSE_WINDOW_S) for key, stamps in answers.items()}
    residuals = trackers(model.metrics, model.responses)
    silences = [Silence(key) for key in model.responses]
    contention = Contention(threshold())
    warm_until = begin + int(max(model.spec.windows) * NS)
    out: list[Step | Alarm] = []
    for index, t_ns in enumerate(times.tolist()):
        warming = t_ns < warm_until
        values = {t: float(measured[t][index]) for t in TARGETS}
        guesses = {t: float(predicted[t][index]) for t in TARGETS}
        said = {key: int(counts[index]) for key, counts in answered.items()}
        other = others[index]
        busy = contention.busy(other)
        out.append(Step(t_ns, warming, int(received[index]), said, values, guesses, other, busy))
        if not warming:
            count = int(received[index])
            out += judge_step(residuals, silences, values, guesses, count, said, busy)
    return out


def _other_cpu(run: Run, times: np.ndarray) -> list[float | None]:
    """What else used the host at each step (`redline.predict.watch.other_cpu`): the host's CPU
    less every monitored process's and Redline's own, each the mean of its samples in the step;
    None at every step of a recording without the host's or Redline's samples."""
    host, own = run.context.get(HOST_PROCESS), run.context.get(OWN_PROCESS)
    if not host or not own or run.cores <= 0:
        return [None] * len(times)
    host_cpu = step_targets(host, times, ("cpu_percent", "cpu_steal_percent"))
    used = sum(
        (
            np.nan_to_num(step_targets(samples, times, ("cpu_percent",))["cpu_percent"])
            for samples in [own, *run.samples.values()]
        ),
        np.zeros(len(times)),
    )
    return [
        other_cpu(
            {name: float(values[index]) for name, values in host_cpu.items()},
            float(used[index]),
            run.cores,
        )
        for index in range(len(times))
    ]
