"""Which earlier revisions make a series' baseline: the ``recent`` policy, shared by the worker
and the offline evaluation so that both judge exactly the same comparison (but for flags their
pairs confirmed, `Flag.CONFIRMED`: the evaluation runs no pairs, and a re-analysis settles
confirmations only at its end).

``recent``: the newest earlier revisions, newest first, pooled until they hold the method's
``baseline_values`` values (samples, or executions for an execution-level method), at most
``window`` revisions, and never reaching back past the newest revision at which the same method
flagged a change that the revisions since have not left (`restarts`). That revision is the
first of the new level: after a change, the baseline restarts there, so the revisions after a
real change are compared with the changed level rather than flagged again and again until the
old level leaves the window (as Perfherder and Otava restart their windows at a detected change
point). A flag the revisions after it returned from is a spike, not a level: the baseline
goes on past it. Before, every flag restarted it, spikes included, and the next revisions were
judged against the spike alone: with one execution each, "not enough data" for five revisions,
and then a baseline that still began at the spike, so a real change in those revisions was
pooled in unjudged (a trial's history lost a confirmed +40 % regression this way).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from enum import IntEnum
from typing import Generic, TypeVar

import numpy as np
from redline.detect.confirmation import DEFAULT_CONFIRM_REVISIONS, DROPPED, hold

#: How many earlier revisions ``recent`` may pool at most, by default (configurable: ``window``).
DEFAULT_WINDOW = 10


class Flag(IntEnum):
    """A revision's flag as `take_recent` reads it (a bool reads as NONE or UNDECIDED)."""

    NONE = 0
    #: flagged, not yet decided by its pairs: the revisions after it decide (`restarts`)
    UNDECIDED = 1
    #: flagged, and its pairs confirmed it: a level, never read past as an undecided one
    CONFIRMED = 2


T = TypeVar("T")


def lookback(window: int) -> int:
    """How many earlier revisions with results a baseline of at most ``window`` revisions may
    look through: a revision whose every run of a series was measured while the host was busy
    gives it no values and does not use the window up. Without it, six busy revisions in a row
    filled a window of 10 (`bench_verdicts`, 2026-11-28): the quiet revision after them had
    "too few samples", and a leak and CPU +30 % made during the busy spell went into the
    baseline unflagged. Twice the window: a longer busy spell leaves the revision after it
    undecided rather than judged against a baseline that old."""
    return 2 * window


class _Lazy(Generic[T]):
    """The items of an iterable, read only as far as asked."""

    def __init__(self, items: Iterable[tuple[T, np.ndarray, int]]) -> None:
        self._source: Iterator[tuple[T, np.ndarray, int]] = iter(items)
        self._read: list[tuple[T, np.ndarray, int]] = []

    def get(self, k: int) -> tuple[T, np.ndarray, int] | None:
        while len(self._read) <= k:
            item = next(self._source, None)
            if item is None:
                return None
            self._read.append(item)
        return self._read[k]


def restarts(
    before: Sequence[np.ndarray],
    flagged: np.ndarray,
    since: Sequence[np.ndarray],
    wait: int = DEFAULT_CONFIRM_REVISIONS,
    count: bool = False,
) -> bool:
    """Whether a baseline restarts at a flagged revision (its values ``flagged``; ``before``:
    those of the revisions before it, its own baseline; ``since``: those of the revisions
    between it and the one judged, oldest first): yes until ``wait`` of them measured the
    series, then unless they returned towards the old level (`redline.detect.confirmation.hold`,
    the test confirmation by history applies, on the values at hand)."""
    pooled = [v for v in before if len(v)]
    if not pooled:
        return True
    return hold(np.concatenate(pooled), flagged, list(since), wait, count=count).state != DROPPED


def take_recent(
    newest_first: Iterable[tuple[T, np.ndarray, int]],
    need: int,
    window: int = DEFAULT_WINDOW,
    wait: int = DEFAULT_CONFIRM_REVISIONS,
    count: bool = False,
    past_undecided: bool = False,
) -> list[T]:
    """The earlier revisions that form the baseline, taken from ``(revision, its values,
    flagged by the method: a `Flag`)`` newest first, and read no further than needed (the
    iterable may compute each revision's values lazily). ``wait``: the
    revisions after a flag that decide whether it was a spike (`restarts`); ``count``: the
    values count rare events; ``past_undecided``: leave out a flag fewer than ``wait`` revisions
    after it measured the series, unless its pairs confirmed it, and read on past it, as if it
    had not restarted the baseline (the level before it, `redline.detect.suspected`)."""
    items: _Lazy[T] = _Lazy(newest_first)
    taken: list[T] = []
    pooled = 0
    k = 0
    while len(taken) < window and pooled < need and (entry := items.get(k)) is not None:
        item, values, flagged = entry
        if flagged == Flag.UNDECIDED and past_undecided and k < wait:  # k revisions since it
            k += 1
            continue
        taken.append(item)
        pooled += len(values)
        if flagged and _restarts_at(items, k, need, window, wait, count):
            break  # the newest change the method flagged that held: the baseline starts there
        k += 1
    return taken


def _restarts_at(items: _Lazy[T], k: int, need: int, window: int, wait: int, count: bool) -> bool:
    """`restarts` at the ``k``-th newest revision, its own baseline read as `take_recent` reads
    one (up to the flag before it, that one included), but past a flag at most ``wait``
    revisions before it and `Flag.UNDECIDED`, which it may have been judged past
    (`redline.detect.suspected`): a spike and the flag the other way right after it (a change
    against the level before the spike) were otherwise judged by the spike's one value, which
    "held" it."""
    since = [entry[1] for j in range(k - 1, -1, -1) if (entry := items.get(j)) is not None]
    if len(since) < wait:
        return True  # cheap, and the common case right after a flag
    flagged = items.get(k)
    assert flagged is not None
    before: list[np.ndarray] = []
    j = k + 1
    while len(before) < window and sum(map(len, before)) < need:
        entry = items.get(j)
        if entry is None:
            break
        j += 1
        if entry[2] == Flag.UNDECIDED and j - k - 1 <= wait:  # at most wait before it
            continue
        before.append(entry[1])
        if entry[2]:
            break
    return restarts(before, flagged[1], since, wait, count)


def recent_depth(
    values_newest_first: Sequence[np.ndarray],
    need: int,
    window: int = DEFAULT_WINDOW,
    flagged: Callable[[int], bool] = lambda _k: False,
    wait: int = DEFAULT_CONFIRM_REVISIONS,
    count: bool = False,
    past_undecided: bool = False,
) -> int:
    """How many of the newest earlier revisions form the baseline (`take_recent` on values).

    ``flagged``: whether the method flagged the revision at that position of
    ``values_newest_first``.
    """
    return len(
        take_recent(
            ((k, values, flagged(k)) for k, values in enumerate(values_newest_first)),
            need,
            window,
            wait,
            count,
            past_undecided,
        )
    )
