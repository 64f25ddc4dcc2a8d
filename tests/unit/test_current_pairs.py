"""Which confirmation pairs of a revision count (`services.jobs.current_pairs`): the pairs are
queued once per baseline, and a revision judged again against another baseline (one arriving
late) has its newest pairs judged, never a mix of comparisons."""

from __future__ import annotations

from redline.server.models import Job
from redline.server.services.jobs import current_pairs

CANDIDATE = 5


def _pairs(*baselines: int) -> list[Job]:
    """Two jobs per pair, numbered from 1, the baseline's then the candidate's."""
    return [
        Job(id=2 * pair + side, revision_id=(baseline, CANDIDATE)[side], pair=pair)
        for pair, baseline in enumerate(baselines, start=1)
        for side in (0, 1)
    ]


def test_no_pairs_have_no_baseline() -> None:
    assert current_pairs([], CANDIDATE) == (None, [])


def test_pairs_against_one_baseline_all_count() -> None:
    jobs = _pairs(4, 4)
    assert current_pairs(jobs, CANDIDATE) == (4, jobs)


def test_pairs_queued_against_an_earlier_baseline_do_not_count() -> None:
    jobs = _pairs(4, 4, 45, 45)  # judged again against r4.5, which arrived late
    baseline, newest = current_pairs(jobs, CANDIDATE)
    assert baseline == 45 and [job.pair for job in newest] == [3, 3, 4, 4]


def test_a_baseline_that_came_back_counts_only_its_newest_pairs() -> None:
    """A -> B -> A: the first pairs against A were superseded; they are not this comparison's
    (the review of 2026-11-27 found them counted among the pairs)."""
    jobs = _pairs(4, 4, 45, 45, 4, 4)
    baseline, newest = current_pairs(jobs, CANDIDATE)
    assert baseline == 4 and [job.pair for job in newest] == [5, 5, 6, 6]
