"""The baseline policy: for each series and method, which earlier revisions' values a revision is
judged against (``recent``, ``previous``, ``window`` or ``pinned``; `redline.detect.config`)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from itertools import islice
from typing import TYPE_CHECKING

import numpy as np
from redline.detect.baseline import Flag, lookback, take_recent
from redline.detect.config import DetectionConfig
from redline.detect.count_rate import CountRate
from redline.detect.execution_shift import HELD_AFTER, ExecutionShift, strongest_step
from redline.detect.methods import Detector, Levelled
from redline.detect.result import Detection
from redline.detect.suspected import BEFORE, OLDER, LevelBefore, after_flag
from redline.server.models import Execution, Revision
from redline.server.services.reach import ingested_executions
from redline.worker.history import (
    earlier_than,
    flagged_and_confirmed,
    previous_revisions,
    undecided_verdicts,
)
from redline.worker.samples import SampleCache, read_samples
from sqlalchemy import func, select
from sqlalchemy.orm import Session

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from redline.worker.reanalysis import Walk


@dataclass(frozen=True)
class Baseline:
    values: np.ndarray | None
    newest: int | None = None  # the newest baseline revision
    revisions: int = 0
    missing: str = ""


@dataclass(frozen=True)
class Step:
    """A step looked for at an earlier revision: one that could not be judged when it was
    measured (`Baselines.step`), or whose own run showed no change (`Baselines.held`): that
    revision, what was before it, its values and those after it, and what was found."""

    revision_id: int
    before: Baseline
    after: np.ndarray
    found: Detection

    @property
    def values_before(self) -> int:
        return 0 if self.before.values is None else len(self.before.values)


class Baselines:
    """Each series' baseline for each method under the configuration."""

    def __init__(
        self,
        session: Session,
        revision: Revision,
        config: DetectionConfig,
        series_ids: list[int],
        walk: Walk | None = None,
    ) -> None:
        """``walk``: what a re-analysis knows of the earlier revisions; else it is read."""
        self.session, self.config = session, config
        #: each (series, method)'s baseline revisions with their values (`_revisions`): asked by
        #: the verdict, the held level and the notes on it; forgotten when the baseline restarts
        self._taken: dict[tuple[int, str], list[tuple[int, np.ndarray]]] = {}
        #: per earlier revision, its series no execution may be judged by, with why
        self._unjudged: dict[int, dict[int, str]] = {}
        self.cache = walk.cache if walk else SampleCache(lookback(config.window) + 1)
        self.pinned: int | None = None
        self.flagged: set[tuple[int, str, int]] = walk.flagged if walk else set()
        #: the earlier (series, method, revision) judged "not enough data": a step may be there
        self.undecided: set[tuple[int, str, int]] = walk.undecided if walk else set()
        #: the earlier flags their pairs confirmed as changes: a re-analysis settles
        #: confirmations at its end, so its walk knows none, and judges by the revisions after
        #: them alone (a known difference, where a flag's pairs confirmed it)
        self.confirmed: set[tuple[int, str, int]] = set()
        if config.baseline == "pinned":
            self.pinned = session.scalar(
                select(Revision.id).where(
                    Revision.component_id == revision.component_id,
                    Revision.title == config.pinned,
                    earlier_than(revision),
                )
            )
            self.previous: dict[int, list[int]] = {}
            return
        depth = 1 if config.baseline == "previous" else lookback(config.window)
        self.previous = previous_revisions(
            session, revision, series_ids, depth, walk.newest_first() if walk else None
        )
        if config.baseline == "recent" and walk is None:
            earlier = {r for ids in self.previous.values() for r in ids}
            self.flagged, self.confirmed = flagged_and_confirmed(session, earlier, series_ids)
            self.undecided = undecided_verdicts(session, earlier, series_ids)

    def values(self, revision_id: int, series_id: int, detector: Levelled) -> np.ndarray | None:
        return self.cache.values(self.session, revision_id, series_id, detector)

    def _revisions(self, series_id: int, detector: Levelled) -> list[tuple[int, np.ndarray]]:
        """The baseline's revisions, newest first, with the detector's values of the series."""
        key = (series_id, detector.name)
        if key not in self._taken:
            self._taken[key] = self._take(series_id, detector)
        return self._taken[key]

    def _take(
        self,
        series_id: int,
        detector: Levelled,
        past_undecided: bool = False,
        before: int | None = None,
    ) -> list[tuple[int, np.ndarray]]:
        """The baseline's revisions with their values, newest first; ``before``: the baseline
        of that earlier revision as ``recent`` reads it from there, among the revisions this one
        looks through; ``past_undecided``: leaving out the flags not yet decided there
        (`take_recent`)."""
        if self.config.baseline == "pinned":
            ids = [self.pinned] if self.pinned is not None else []
        else:
            ids = self.previous.get(series_id, [])
        if before is not None:
            ids = ids[ids.index(before) + 1 :] if before in ids else []
        present = (
            (i, values) for i in ids if (values := self.values(i, series_id, detector)) is not None
        )
        if self.config.baseline == "window":  # the last ``window`` that give it values
            return list(islice(present, self.config.window))
        if self.config.baseline != "recent":
            return list(present)
        return take_recent(
            (((i, values), values, self._flag(series_id, detector.name, i))
             for i, values in present),
            detector.baseline_values,
            self.config.window,
            self.config.confirm_revisions,
            count=isinstance(detector, CountRate),
            past_undecided=past_undecided,
        )  # fmt: skip

    def _flag(self, series_id: int, method: str, revision_id: int) -> Flag:
        """The revision's flag as `take_recent` reads it."""
        key = (series_id, method, revision_id)
        if key in self.confirmed:
            return Flag.CONFIRMED
        return Flag.UNDECIDED if key in self.flagged else Flag.NONE

    def after_flag(
        self,
        series_id: int,
        detector: Detector,
        counter: str,
        candidate: np.ndarray | None,
        base: Baseline,
        verdict: Detection,
    ) -> tuple[Baseline, Detection]:
        """The verdict and its baseline where the series' baseline restarted at a flag and was
        too short to judge by (`redline.detect.suspected`): while the revisions after the flag
        have not yet decided it, judged against the level before it too (`past_suspected`;
        where that is a short level its pairs confirmed, with the noise of the levels before
        it: `_level_before`); once they held it, against the new level with the noise of the
        one before it (`at_new_level`)."""
        if verdict.decided or candidate is None or base.values is None:
            return base, verdict
        taken = self._revisions(series_id, detector)
        if (
            self.config.baseline != "recent"
            or detector.ndim == 2  # as the evaluation: methods judging counters together
            or not taken
            or (series_id, detector.name, taken[-1][0]) not in self.flagged
        ):
            return base, verdict
        confirmed = (series_id, detector.name, taken[-1][0]) in self.confirmed
        older = self._take(series_id, detector, past_undecided=True, before=taken[-1][0])
        if not older:
            return base, verdict
        flag = self.session.get(Revision, taken[-1][0])
        before, noise_revisions = self._level_before(series_id, detector, older)
        found, against = after_flag(
            verdict,
            detector,
            counter,
            base.values,
            before,
            candidate,
            flag.title if flag is not None else str(taken[-1][0]),
            # held by the revisions after it, or confirmed by its pairs: a trial's regression,
            # confirmed by 2 of 2 pairs and reverted by the next commit, was judged against the
            # level before it ("no change"), pooled into the next one's baseline with the
            # revert, and a +30 % commit after the revert passed CI (2026-12-07)
            held=len(taken) > self.config.confirm_revisions,
            confirmed=confirmed,
        )
        if against == BEFORE:
            return Baseline(before.values, older[0][0], len(older)), found
        if against == OLDER:
            # named by the flag that returned to that level, not by the level's newest revision:
            # a range from there would overlap the confirmed regression and join it (silent
            # when it was triaged fixed, as a reverted one is), and its pairs run against the
            # flag, at the same level
            return Baseline(before.noise, taken[-1][0], noise_revisions), found
        return base, found

    def _level_before(
        self, series_id: int, detector: Detector, older: list[tuple[int, np.ndarray]]
    ) -> tuple[LevelBefore, int]:
        """The level before a flag (``older``: its revisions, newest first), and where it is a
        level its pairs confirmed too short to judge by, the nearest level before it that is
        long enough (read past other short confirmed ones; `LevelBefore.noise`), with how many
        revisions that one holds."""
        values = np.concatenate([v for _, v in older])
        need = detector.min_baseline
        start = older[-1][0]
        if len(values) >= need or (series_id, detector.name, start) not in self.confirmed:
            return LevelBefore(values), 0
        since = self.session.get(Revision, start)
        at = since.title if since is not None else str(start)
        while more := self._take(series_id, detector, past_undecided=True, before=start):
            noise = np.concatenate([v for _, v in more])
            if len(noise) >= need:
                return LevelBefore(values, noise, at), len(more)
            start = more[-1][0]
            if (series_id, detector.name, start) not in self.confirmed:
                break
        return LevelBefore(values), 0

    def step(self, series_id: int, detector: Levelled, candidate: np.ndarray | None) -> Step | None:
        """A step at one of the baseline's revisions that could not be judged when measured
        (too few values before them: a new history, or executions left out as disturbed),
        judged now that this revision and those between add values after it (`strongest_step`):
        without it, such a change would pool into the baseline and either never be found or be
        found at a later, innocent revision. Only for `ExecutionShift`'s kind under ``recent``,
        and not in a baseline restarted at a flagged change (see below)."""
        if (
            self.config.baseline != "recent"
            or not isinstance(detector, ExecutionShift)
            or candidate is None
            or not any(
                (series_id, detector.name, revision_id) in self.undecided
                for revision_id in self.previous.get(series_id, [])
            )  # the common case, answered without gathering the baseline
        ):
            return None
        oldest_first = self._revisions(series_id, detector)[::-1]
        if not oldest_first or (series_id, detector.name, oldest_first[0][0]) in self.flagged:
            # a baseline restarted at a flagged change: a revision after it that differs says
            # whether that change held, which confirmation by history settles, not a new step
            return None
        at = [
            k
            for k, (revision_id, _) in enumerate(oldest_first)
            if k > 0 and (series_id, detector.name, revision_id) in self.undecided
        ]
        if not at:
            return None
        stretches = [values[np.isfinite(values)] for _, values in oldest_first]
        best = strongest_step(detector, [*stretches, candidate[np.isfinite(candidate)]], at)
        if best is None:
            return None
        k, found = best
        before = oldest_first[:k]
        return Step(
            oldest_first[k][0],
            Baseline(np.concatenate(stretches[:k]), before[-1][0], len(before)),
            np.concatenate([*stretches[k:], candidate[np.isfinite(candidate)]]),
            found,
        )

    def held(self, series_id: int, detector: Levelled, candidate: np.ndarray | None) -> Step | None:
        """The revision `HELD_AFTER` revisions back, this one included, judged again on their
        values (`ExecutionShift.held`) against the earlier baseline revisions', when its own
        run(s) showed no change: where they hold a new level, as a `Step` (found or not).
        None where it cannot be asked: another baseline policy or method, a revision judged
        otherwise than "no change" (flagged, or not enough data) at or after it, fewer than
        ``min_baseline`` values before it."""
        if (
            self.config.baseline != "recent"
            or not isinstance(detector, ExecutionShift)
            or candidate is None
        ):
            return None
        oldest_first = self._revisions(series_id, detector)[::-1]
        k = len(oldest_first) + 1 - HELD_AFTER
        keys = [(series_id, detector.name, revision_id) for revision_id, _ in oldest_first[k:]]
        if k < 1 or any(key in self.flagged or key in self.undecided for key in keys):
            return None
        stretches = [values[np.isfinite(values)] for _, values in oldest_first]
        before = np.concatenate(stretches[:k])
        if len(before) < detector.min_baseline:
            return None
        after = np.concatenate([*stretches[k:], candidate[np.isfinite(candidate)]])
        return Step(
            oldest_first[k][0],
            Baseline(before, oldest_first[k - 1][0], k),
            after,
            detector.held(before, after),
        )

    def restart(self, series_id: int, detector: Levelled, revision_id: int) -> None:
        """The method now flags the series at ``revision_id``: the baselines start there."""
        key = (series_id, detector.name, revision_id)
        self.flagged.add(key)
        self.undecided.discard(key)
        self._taken.pop((series_id, detector.name), None)

    def left_out(self, series_id: int, detector: Levelled, used: int) -> int:
        """How many executions of the baseline's revisions gave it no value of the series, for
        an execution-level ``detector`` that pooled ``used`` values: measured while the host
        was busy, or without the series (0 for other levels)."""
        taken = self.revisions_of(series_id, detector)
        if detector.level != "execution" or not taken:
            return 0
        # the revisions it reached back over, those that gave no value at all included
        known = self.previous.get(series_id, [])
        ids = known[: known.index(taken[-1]) + 1] if taken[-1] in known else taken
        ingested = self.session.scalar(
            select(func.count())
            .select_from(Execution)
            .where(Execution.revision_id.in_(ids), Execution.id.in_(ingested_executions()))
        )
        return max(0, (ingested or 0) - used)

    def revisions_of(self, series_id: int, detector: Levelled) -> list[int]:
        """The ids of the baseline's revisions of the series for ``detector``, newest first."""
        return [revision_id for revision_id, _ in self._revisions(series_id, detector)]

    def of(self, series_id: int, detector: Levelled) -> Baseline:
        if self.config.baseline == "pinned" and self.pinned is None:
            return Baseline(
                None,
                missing=f"missing baseline: pinned revision "
                f"{self.config.pinned!r} is not an earlier revision",
            )
        found = self._revisions(series_id, detector)
        if not found:
            known = [self.pinned] if self.pinned is not None else self.previous.get(series_id)
            if not known:
                return Baseline(
                    None, missing="missing baseline: no earlier revision has samples of this series"
                )
            return self._unusable(known, series_id)
        return Baseline(np.concatenate([values for _, values in found]), found[0][0], len(found))

    def _unusable(self, revisions: list[int], series_id: int) -> Baseline:
        """No baseline, saying why the earlier revisions that measured the series give no
        values: the host was busy while they measured it (each of its runs disturbed: charted,
        never judged; that revision is named as the baseline, for its fresh run,
        `redline.worker.remeasure`), or their samples are unreadable."""
        for revision_id in revisions:
            if revision_id not in self._unjudged:  # once a revision, whatever the series
                self._unjudged[revision_id] = read_samples(self.session, revision_id)[3]
            disturbed = self._unjudged[revision_id].get(series_id)
            if disturbed:
                title = self.session.get(Revision, revision_id)
                return Baseline(
                    None,
                    newest=revision_id,
                    missing=f"missing baseline: revision {title.title if title else revision_id}"
                    f"'s runs of this series were all disturbed ({disturbed}), and no earlier "
                    "revision measured it undisturbed",
                )
        return Baseline(
            None,
            missing="missing baseline: the baseline revision's samples of this series are "
            "unreadable or absent",
        )
