"""The stop signal actions watch: an event that a parent's stop or a deadline also sets.

`Stop` is a `threading.Event` whose ``is_set`` and ``wait`` also answer for its parent (so
``LimitedTime`` and ``WithBackground`` can interrupt a subtree without interrupting the whole run)
and for an optional deadline (so a time limit needs no timer thread). Setting a `Stop` sets its
children at once; a plain `threading.Event` parent is polled every `POLL_S`.
"""

from __future__ import annotations

import threading
import time
import weakref

POLL_S = 0.05  # how late a child notices a plain-Event parent being set


class Stop(threading.Event):
    """A stop signal with an optional parent signal and an optional deadline (perf_counter_ns)."""

    _deadline_ns: int | None

    def __init__(
        self, parent: threading.Event | None = None, deadline_ns: int | None = None
    ) -> None:
        super().__init__()
        self._parent = parent
        self._children: weakref.WeakSet[Stop] = weakref.WeakSet()
        inherited = parent._deadline_ns if isinstance(parent, Stop) else None
        deadlines = [d for d in (deadline_ns, inherited) if d is not None]
        self._deadline_ns = min(deadlines) if deadlines else None
        self._polls_parent = parent is not None and not isinstance(parent, Stop)
        if isinstance(parent, Stop):
            parent._children.add(self)
            if parent.is_set():
                super().set()

    def set(self) -> None:
        super().set()
        for child in list(self._children):
            child.set()

    def is_set(self) -> bool:
        if super().is_set():
            return True
        if self._deadline_ns is not None and time.perf_counter_ns() >= self._deadline_ns:
            return True
        return self._parent is not None and self._parent.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        end = None if timeout is None else time.perf_counter() + timeout
        while not self.is_set():
            slices = [] if end is None else [end - time.perf_counter()]
            if self._deadline_ns is not None:
                slices.append((self._deadline_ns - time.perf_counter_ns()) / 1e9)
            if self._polls_parent:
                slices.append(POLL_S)
            step = min(slices) if slices else None
            if step is not None and step <= 0:
                return self.is_set()
            super().wait(step)
        return True
