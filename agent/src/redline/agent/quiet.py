"""Keeping analysis off the CPU while a measurement runs, when both share one machine.

`redline up` runs the agent and the worker side by side. Measured on the example component, a
worker analysing beside a run moved the component's CPU per unit of work by 20–25 %: enough for
detection to report an unchanged revision. So the two share a readers–writer lock file (named by
``REDLINE_MEASUREMENT_LOCK``): a run holds it exclusively, a worker task shares it. A run waits
for the task in progress, and tasks wait for the run. Without the variable (separate hosts, as in
production) the lock does nothing.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager

LOCK_VARIABLE = "REDLINE_MEASUREMENT_LOCK"


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
