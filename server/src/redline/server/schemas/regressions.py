"""Detections, regressions, triage, accuracy, the detection configuration and re-analysis."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field
from redline.detect.baseline import DEFAULT_WINDOW
from redline.detect.config import MAX_CONFIRM_PAIRS, MAX_CONFIRM_REVISIONS, MAX_WINDOW
from redline.detect.confirmation import DEFAULT_CONFIRM_PAIRS, DEFAULT_CONFIRM_REVISIONS
from redline.detect.counters import CONTEXT_COUNTERS
from redline.server.models import RegressionState
from redline.server.schemas.common import RequestBody
from redline.server.schemas.fields import Line, Title
from redline.server.schemas.results import SeriesRef


class DetectionOut(BaseModel):
    id: int
    series: SeriesRef
    revision: str
    baseline: str | None = Field(description="the newest baseline revision; null when missing")
    baseline_revisions: int = Field(description="how many revisions the baseline pools")
    method: str
    verdict: Literal["change", "no change", "not enough data"]
    reason: str = Field(description="what is missing, or why a significant result is no change")
    score: float
    p_value: float | None
    effect: float | None = Field(description="relative change of the mean; null when undefined")
    direction: str
    flagged: bool
    confirmation: Literal["", "suspected", "held", "dropped"] = Field(
        description="of a flagged change for the worse: suspected until the later revisions "
        "say whether it held or was dropped (a spike); empty otherwise"
    )
    confirmation_reason: str = Field(description="the figures behind the confirmation")
    regression_id: int | None


class RegressionEventOut(BaseModel):
    at: datetime
    who: str
    from_state: str
    to_state: str
    comment: str


class RegressionOut(BaseModel):
    id: int
    component: str
    good_revision: str = Field(description="the newest revision before the change")
    bad_revision: str = Field(description="the last revision in the range showing it")
    bad_subject: str = Field(
        default="", description="the first line of bad_revision's commit message, if reported"
    )
    state: RegressionState
    confirmation: Literal["suspected", "confirmed", "not_confirmed", "withdrawn"] = Field(
        description="confirmed when one of its changes held in its confirmation runs or over "
        "the later revisions, not_confirmed when every one was dropped (its reason says why), "
        "suspected until then; withdrawn when its revisions were judged again and none of its "
        "changes was found (its reason says what it had been, with its largest change)"
    )
    confirmation_reason: str
    largest: str = Field(
        default="", description="its largest change in words (not counting those dropped)"
    )
    methods: list[str] = Field(description="methods with a flagged detection in it")
    detections: int
    created: datetime
    updated: datetime


class RevisionBetween(BaseModel):
    title: str
    why: str = Field(
        description="why it is not the good revision: its runs failed, were cancelled, have not "
        "run, did not measure the regression's series, or were measured while the host was busy"
    )


class RegressionDetail(RegressionOut):
    flagged: list[DetectionOut]
    history: list[RegressionEventOut]
    between: list[RevisionBetween] = Field(
        default_factory=list,
        description="the revisions between good_revision and bad_revision other than those with "
        "one of its changes, oldest first (the first 20), each with why it is not the good one "
        "(not judged for its series: its runs failed, were cancelled, have not run, did not "
        "measure them, or the host was busy; or measured within the span of its changes): the "
        "change may be theirs",
    )
    between_count: int = Field(default=0, description="how many such revisions there are in all")
    changed_back: str = Field(
        default="",
        description="where a revision since its change was flagged changing one of its series "
        "the other way (a revert, a fix), the newest, in words; empty otherwise",
    )


class TriageRequest(RequestBody):
    state: RegressionState
    comment: str = Field(default="", max_length=10_000)


class MethodAccuracy(BaseModel):
    method: str
    true_positives: int = Field(description="confirmed or fixed regressions it flagged")
    false_positives: int = Field(description="regressions labelled false_positive it flagged")
    precision: float | None = Field(description="TP / (TP + FP); null before any label")
    unlabelled: int = Field(description="its regressions still new, acknowledged or ignored")


class AccuracyOut(BaseModel):
    component: str
    labelled_regressions: int
    methods: list[MethodAccuracy]


class DetectionConfigIn(RequestBody):
    # a misspelt field ("alarm_method") would otherwise be dropped and its default stored

    methods: list[str] | None = Field(
        default=None, description="default: the evaluated default and ks"
    )
    baseline: Literal["recent", "previous", "window", "pinned"] = Field(
        default="recent",
        description="recent: the newest revisions, pooled until the method "
        "has enough values (at most `window`), restarting at its newest flagged change",
    )
    window: int = Field(default=DEFAULT_WINDOW, ge=1, le=MAX_WINDOW)
    pinned: Title | None = Field(default=None, description="revision title when pinned")
    thresholds: dict[str, dict[str, float | str]] = Field(default_factory=dict)
    context_counters: list[Line] = Field(
        default_factory=lambda: list(CONTEXT_COUNTERS),
        max_length=100,
        description="counters recorded and charted but not judged; by default the user/system "
        "split of CPU, whose total is judged ([] judges every counter)",
    )
    alarm_methods: list[str] = Field(
        default_factory=list,
        max_length=20,
        description="methods whose flagged changes for the worse become regressions (the "
        "others are stored and charted); [] : the first method (execution_shift by default)",
    )
    confirm_pairs: int = Field(
        default=DEFAULT_CONFIRM_PAIRS,
        ge=0,
        le=MAX_CONFIRM_PAIRS,
        description="on a flagged change, run the revision and its baseline again this many "
        "times each, interleaved on one host, and confirm by the pairs (0: off, the later "
        "revisions confirm)",
    )
    confirm_revisions: int = Field(
        default=DEFAULT_CONFIRM_REVISIONS,
        ge=0,
        le=MAX_CONFIRM_REVISIONS,
        description="later revisions a flagged change must hold over before its regression is "
        "confirmed (0: confirmed when flagged)",
    )
    reanalyze: bool = Field(default=True, description="re-analyse the whole history after")


class DetectionConfigOut(BaseModel):
    methods: list[str]
    baseline: str
    window: int
    pinned: str | None
    thresholds: dict[str, dict[str, float | str]]
    context_counters: list[str]
    confirm_revisions: int
    alarm_methods: list[str]
    confirm_pairs: int


class ReanalysisOut(BaseModel):
    component: str
    state: Literal["none", "queued", "running", "done", "failed"]
    #: units of work: one per revision and part (judged), and one per revision (stored)
    total: int
    done: int
    revisions: int = 0  # the revisions planned
    parts: int = 1  # the parts its series were split into, each a task any worker takes
    error: str
    requested: datetime | None
    started: datetime | None
    finished: datetime | None
