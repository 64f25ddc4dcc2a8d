"""Which earlier revisions make a series' baseline: the ``recent`` policy, shared by the worker
and the offline evaluation so that both judge exactly the same comparison.

``recent``: the newest earlier revisions, newest first, pooled until they hold the method's
``baseline_values`` values (samples, or executions for an execution-level method), at most
``window`` revisions, and never reaching back past the newest revision at which the same method
flagged the series. That revision is the first of the new level: after a change, the baseline
restarts there, so the revisions after a real change are compared with the changed level rather
than flagged again and again until the old level leaves the window (as Perfherder and Otava
restart their windows at a detected change point).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TypeVar

#: How many earlier revisions ``recent`` may pool at most, by default (configurable: ``window``).
DEFAULT_WINDOW = 10
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


def take_recent(
    newest_first: Iterable[tuple[T, int, bool]], need: int, window: int = DEFAULT_WINDOW
) -> list[T]:
    """The earlier revisions that form the baseline, taken from ``(revision, number of values,
    flagged by the method)`` newest first, and read no further than needed (the iterable may
    compute each revision's values lazily)."""
    taken: list[T] = []
    pooled = 0
    for item, size, flagged in newest_first:
        if len(taken) >= window or pooled >= need:
            break
        taken.append(item)
        pooled += size
        if flagged:  # the newest change the method flagged: the baseline starts there
            break
    return taken


def recent_depth(
    sizes_newest_first: Sequence[int],
    need: int,
    window: int = DEFAULT_WINDOW,
    flagged_at: int | None = None,
) -> int:
    """How many of the newest earlier revisions form the baseline (`take_recent` on sizes).

    ``flagged_at``: the position in ``sizes_newest_first`` of the newest revision the method
    flagged, or None; the baseline stops there, that revision included.
    """
    return len(
        take_recent(
            ((k, size, k == flagged_at) for k, size in enumerate(sizes_newest_first)), need, window
        )
    )
