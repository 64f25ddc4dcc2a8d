"""Keeping analysis off the CPU while a measurement runs, when both share one machine.

`redline up` runs the agent and the worker side by side. Measured on the example component, a
worker analysing beside a run moved the component's CPU per unit of work by 20–25 %: enough for
detection to report an unchanged revision. So the two share a readers–writer lock file (named by
``REDLINE_MEASUREMENT_LOCK``): a run holds it exclusively, a worker task shares it. A run waits
for the task in progress, and tasks wait for the run. Without the variable (separate hosts, as in
production) the lock does nothing.

`wait_for_quiet` holds an execution run again after a busy host until the host is quiet: run
again at once, a retry met the same load (a trial's first demo ran its first two jobs three
times each while something used 94-96 % of a core for about 45 s, and judged none of them).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from redline.agent.sampling import HostSampler

LOCK_VARIABLE = "REDLINE_MEASUREMENT_LOCK"
#: a run again after a busy host waits until the host's load stays under the disturbance
#: threshold for this many one-second samples in a row ...
QUIET_SAMPLES = 3
#: ... for at most this long by default (`redline agent --quiet-wait`); then it runs anyway
#: (its recording says whether it was busy)
QUIET_WAIT_S = 60.0


@contextmanager
def _flock(operation: int) -> Iterator[None]:
    path = os.environ.get(LOCK_VARIABLE)
    if not path:
        yield
        return
    with open(path, "a+b") as handle:
        fcntl.flock(handle, operation)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def measuring() -> contextlib.AbstractContextManager[None]:
    """Held by the agent around a run: no worker task runs meanwhile."""
    return _flock(fcntl.LOCK_EX)


def analysing() -> contextlib.AbstractContextManager[None]:
    """Held by a worker task: no run starts meanwhile (tasks do not exclude each other)."""
    return _flock(fcntl.LOCK_SH)


def host_load(sampler: HostSampler) -> float | None:
    """What the host's cores are busy with (stolen time included), in % of one core, since the
    sampler's previous sample; None on its first."""
    values = sampler.sample()
    if "cpu_percent" not in values:
        return None
    stolen = values.get("cpu_steal_percent", 0.0)
    return (values["cpu_percent"] + stolen) * (os.cpu_count() or 1)


def wait_for_quiet(
    limit: float,
    most_s: float = QUIET_WAIT_S,
    sleep: Callable[[float], None] = time.sleep,
    load: Callable[[HostSampler], float | None] = host_load,
) -> float | None:
    """Wait until the host's load (an agent between runs uses next to none of it) stays under
    ``limit`` (% of one core) for `QUIET_SAMPLES` seconds in a row: the seconds waited, or None
    when it did not within ``most_s`` (none at all for 0: at once)."""
    if most_s <= 0:
        return 0.0
    sampler = HostSampler()
    try:
        load(sampler)  # the first sample has no rate yet
        quiet, waited = 0, 0.0
        while waited < most_s:
            sleep(1.0)
            waited += 1.0
            now = load(sampler)
            quiet = quiet + 1 if now is not None and now < limit else 0
            if quiet >= QUIET_SAMPLES:
                return waited
        return None
    finally:
        sampler.close()
