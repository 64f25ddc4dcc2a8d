"""What detection produces before it is stored: `Detection` rows as bulk-insert values, the
charted method's decided verdicts as `KsChange` (what a detection run reports), and one
revision's `Judged` result."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any

import numpy as np
from redline.detect.config import CHARTED_METHOD
from redline.detect.result import NOT_ENOUGH_DATA
from redline.detect.result import Detection as Verdict
from redline.detect.verdict import floored
from redline.server.models import utcnow
from redline.worker.baselines import Baseline, Step


def detection_row(
    series_id: int, revision_id: int, base: Baseline, verdict: Verdict
) -> dict[str, Any]:
    """A `Detection` row, as the values of a bulk insert."""
    effect = verdict.effect if verdict.decided and np.isfinite(verdict.effect) else None
    return dict(
        series_id=series_id,
        revision_id=revision_id,
        baseline_revision_id=base.newest,
        baseline_revisions=base.revisions,
        method=verdict.method,
        verdict=verdict.verdict,
        reason=verdict.reason,
        score=float(verdict.score),
        p_value=None if verdict.p_value is None else float(verdict.p_value),
        effect=None if effect is None else float(effect),
        direction=verdict.direction,
        flagged=bool(verdict.flagged),
        confirmation="",  # a change for the worse becomes suspected when grouped
        confirmation_reason="",
        created=utcnow(),
    )


def step_row(
    series_id: int, step: Step | None, counter: str, reason: Callable[[Step], str]
) -> dict[str, Any] | None:
    """The row of the earlier revision ``step`` was looked for at, when a step is found there
    beyond the counter's floor (`floored`), its reason ``reason(step)``; else None."""
    if step is None:
        return None
    assert step.before.values is not None
    found = floored(step.found, counter, step.before.values, step.after)
    if not found.flagged:
        return None
    found = replace(found, reason=reason(step))
    return detection_row(series_id, step.revision_id, step.before, found)


@dataclass(frozen=True)
class KsChange:
    """KS's decided comparison of a series: what `detect_revision` reports and the trend charts
    draw (plain data: 100 series a revision made ORM objects a re-analysis's largest cost)."""

    series_id: int
    revision_id: int
    baseline_revision_id: int | None
    method: str
    score: float
    p_value: float
    effect: float
    flagged: bool
    created: datetime


def ks_change(row: dict[str, Any], verdict: Verdict) -> KsChange | None:
    if (
        row["method"] != CHARTED_METHOD
        or verdict.verdict == NOT_ENOUGH_DATA
        or verdict.p_value is None
    ):
        return None
    return KsChange(
        series_id=row["series_id"],
        revision_id=row["revision_id"],
        baseline_revision_id=row["baseline_revision_id"],
        method=CHARTED_METHOD,
        score=float(verdict.score),
        p_value=float(verdict.p_value),
        effect=float(verdict.effect),
        flagged=bool(verdict.flagged),
        created=row["created"],
    )


@dataclass(frozen=True)
class Judged:
    """One revision's verdicts and KS changes, computed and not yet stored, and the ingested
    executions they were computed from."""

    revision_id: int
    rows: list[dict[str, Any]]
    changes: list[KsChange]
    executions: tuple[int, ...]
