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

from collections.abc import Sequence

#: How many earlier revisions ``recent`` may pool at most, by default (configurable: ``window``).
DEFAULT_WINDOW = 10


def recent_depth(sizes_newest_first: Sequence[int], need: int, window: int = DEFAULT_WINDOW,
                 flagged_at: int | None = None) -> int:
    """How many of the newest earlier revisions form the baseline.

    ``sizes_newest_first``: each earlier revision's number of values, the newest first.
    ``flagged_at``: the position in that list of the newest revision the method flagged, or
    None; the baseline stops there, that revision included.
    """
    limit = min(len(sizes_newest_first), window)
    if flagged_at is not None:
        limit = min(limit, flagged_at + 1)
    pooled, depth = 0, 0
    while depth < limit and pooled < need:
        pooled += sizes_newest_first[depth]
        depth += 1
    return depth
