"""Counts of rare events judged as counts: did timeouts (or losses) become more frequent?

A driver's timeouts are mostly zero per segment, so the mean of the counts says little and a
test on it less. `CountRate` compares the rate of the events, out of what they could have
happened to (queries sent, samples expected), pooled over each side's executions: Fisher's exact
test on the 2 x 2 table, and a change also needs the rate to move by ``min_rate`` (absolute, a
fraction of the events) so that one timeout in a million queries is not a regression. A rate
that was 0 and is not any more is the typical regression it finds (6 of 6 queries timing out
against 0 of 4,217). Defaults: ``alpha = 0.001`` as the other methods' significance;
``min_rate = 0.001`` (0.1 percentage point), ours.
"""

from __future__ import annotations

import math

from redline.detect.result import CHANGE, NO_CHANGE, Detection, direction_of, not_enough

METHOD = "count_rate"


class CountRate:
    """``compare(events_b, total_b, events_c, total_c)``: the baseline's and the candidate's
    events out of their totals (each summed over the side's executions)."""

    name = METHOD
    #: a worker reduces each execution to one value (a segment's count is one already), and a
    #: ``recent`` baseline pools six executions' counts (`redline.detect.baseline`)
    level = "execution"
    baseline_values = 6

    def __init__(self, alpha: float = 0.001, min_rate: float = 0.001) -> None:
        self.alpha = alpha
        self.min_rate = min_rate

    def get_params(self) -> dict[str, float]:
        """Its parameters, as a `redline.detect.methods.Detector` gives them."""
        return {"alpha": self.alpha, "min_rate": self.min_rate}

    def compare(
        self, events_b: float, total_b: float, events_c: float, total_c: float
    ) -> Detection:
        counts = (events_b, total_b, events_c, total_c)
        if not all(math.isfinite(value) and value >= 0 for value in counts):
            return not_enough(METHOD, "counts must be finite and not negative")
        if total_b <= 0 or total_c <= 0:
            side = "baseline" if total_b <= 0 else "candidate"
            return not_enough(METHOD, f"the {side} counted no events to rate (nothing sent)")
        if events_b > total_b or events_c > total_c:
            return not_enough(METHOD, "more events than what they were counted out of")
        rate_b, rate_c = events_b / total_b, events_c / total_c
        table = [
            [round(events_c), round(total_c - events_c)],
            [round(events_b), round(total_b - events_b)],
        ]
        from scipy.stats import fisher_exact  # where it runs: see `redline.detect`

        p_value = float(fisher_exact(table)[1])
        moved = rate_c - rate_b
        significance = max(0.0, math.log10(max(p_value, 1e-300)) / math.log10(self.alpha))
        score = min(significance, abs(moved) / self.min_rate)
        flagged = p_value < self.alpha and abs(moved) >= self.min_rate
        return Detection(
            method=METHOD,
            verdict=CHANGE if flagged else NO_CHANGE,
            score=score,
            p_value=p_value,
            effect=moved,
            direction=direction_of(moved),
            reason=f"rate {rate_b:.3%} -> {rate_c:.3%} ({events_c:g} of "
            f"{total_c:g}, against {events_b:g} of {total_b:g})",
        )
