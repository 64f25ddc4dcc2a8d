"""Tables of detection and triage: per-component configuration, every method's verdict per series
and revision, regressions grouped from flagged verdicts with their triage history, re-analyses."""

from __future__ import annotations

import enum
from datetime import datetime
from typing import TYPE_CHECKING, Any

from redline.server.models.base import Base, utcnow
from sqlalchemy import (
    JSON,
    Boolean,
    Enum,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

if TYPE_CHECKING:
    from redline.server.models.results import Series
    from redline.server.models.work import Revision


class RegressionState(enum.StrEnum):
    new = "new"
    acknowledged = "acknowledged"
    confirmed = "confirmed"
    fixed = "fixed"
    ignored = "ignored"
    false_positive = "false_positive"


#: A regression's confirmation once judging again finds none of its changes: kept, saying what
#: it had been (`redline.worker.grouping`), not deleted (a trial's regression vanished, and the
#: alert's link to it with it)
WITHDRAWN = "withdrawn"
#: The regressions that stand: those the re-runs or the later revisions confirmed and those
#: still suspected (the regressions page's default; a filter value of the list, "standing")
STANDING = ("suspected", "confirmed")
#: Triage states in which a regression is still open (not fixed, ignored or a false positive)
OPEN_STATES = (RegressionState.new, RegressionState.acknowledged, RegressionState.confirmed)

#: Triage labels as ground truth for a method's precision (ignored, new, acknowledged: no label).
TRUE_POSITIVE_STATES = frozenset({RegressionState.confirmed, RegressionState.fixed})
FALSE_POSITIVE_STATES = frozenset({RegressionState.false_positive})


class DetectionConfigRow(Base):
    """A component's detection configuration (`redline.detect.config.DetectionConfig`)."""

    __tablename__ = "detection_config"
    component_id: Mapped[int] = mapped_column(ForeignKey("component.id"), primary_key=True)
    config: Mapped[dict[str, Any]] = mapped_column(JSON)
    updated: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)


class JudgingConfig(Base):
    """A detection configuration as a component's verdicts were judged by: its fields and each
    method's parameters as they judged (defaults filled in), one row per distinct one
    (``digest``), so a verdict can say what judged it after the configuration changed again
    (a save with ``"reanalyze": false`` keeps the old verdicts; the "why flagged" page showed
    the new thresholds beside them)."""

    __tablename__ = "judging_config"
    __table_args__ = (UniqueConstraint("component_id", "digest"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int] = mapped_column(ForeignKey("component.id", ondelete="CASCADE"))
    digest: Mapped[str] = mapped_column(String(64))
    config: Mapped[dict[str, Any]] = mapped_column(JSON)
    #: method name -> its parameters as it judged (`redline.detect.config.DetectionConfig.detector`)
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    created: Mapped[datetime] = mapped_column(default=utcnow)


class Regression(Base):
    """Flagged detections of one component whose revision ranges overlap.

    The range is (good, bad]: the change happened after ``good_revision`` (the newest baseline
    revision) and shows at ``bad_revision``; the order keys are copied for the overlap query.
    """

    __tablename__ = "regression"
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int] = mapped_column(ForeignKey("component.id"), index=True)
    good_revision_id: Mapped[int] = mapped_column(ForeignKey("revision.id"))
    bad_revision_id: Mapped[int] = mapped_column(ForeignKey("revision.id"))
    good_key: Mapped[str] = mapped_column(String(1000, collation="C"))
    bad_key: Mapped[str] = mapped_column(String(1000, collation="C"))
    state: Mapped[RegressionState] = mapped_column(
        Enum(RegressionState, name="regression_state", native_enum=False, length=20),
        default=RegressionState.new,
        index=True,
    )
    #: suspected, confirmed or not_confirmed (`redline.worker.confirmation`), or WITHDRAWN
    confirmation: Mapped[str] = mapped_column(String(20), default="suspected", index=True)
    confirmation_reason: Mapped[str] = mapped_column(Text, default="")
    created: Mapped[datetime] = mapped_column(default=utcnow)
    updated: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    good_revision: Mapped[Revision] = relationship(foreign_keys=[good_revision_id])
    bad_revision: Mapped[Revision] = relationship(foreign_keys=[bad_revision_id])
    events: Mapped[list[RegressionEvent]] = relationship(
        order_by="RegressionEvent.id", cascade="all, delete-orphan"
    )


class RegressionEvent(Base):
    """One triage step: who moved the regression from one state to another, when, and why."""

    __tablename__ = "regression_event"
    id: Mapped[int] = mapped_column(primary_key=True)
    regression_id: Mapped[int] = mapped_column(
        ForeignKey("regression.id", ondelete="CASCADE"), index=True
    )
    at: Mapped[datetime] = mapped_column(default=utcnow)
    who: Mapped[str] = mapped_column(String(200))
    from_state: Mapped[str] = mapped_column(String(20))
    to_state: Mapped[str] = mapped_column(String(20))
    comment: Mapped[str] = mapped_column(Text, default="")


class VerdictColumns:
    """The columns of a method's verdict, a stored `Detection`'s and a staged one's."""

    baseline_revisions: Mapped[int] = mapped_column(Integer, default=0)
    method: Mapped[str] = mapped_column(String(50))
    verdict: Mapped[str] = mapped_column(String(20))
    reason: Mapped[str] = mapped_column(Text, default="")
    score: Mapped[float] = mapped_column(Float, default=0.0)
    p_value: Mapped[float | None] = mapped_column(Float, default=None)
    effect: Mapped[float | None] = mapped_column(Float, default=None)  # None when undefined
    direction: Mapped[str] = mapped_column(String(10), default="none")
    flagged: Mapped[bool] = mapped_column(Boolean, default=False)
    #: of a flagged change for the worse: suspected, held or dropped (`detect.confirmation`)
    confirmation: Mapped[str] = mapped_column(String(20), default="")
    confirmation_reason: Mapped[str] = mapped_column(Text, default="")
    created: Mapped[datetime] = mapped_column(default=utcnow)


class Detection(VerdictColumns, Base):
    """One method's verdict on one series of one revision against its baseline.

    ``verdict`` is "change", "no change" or "not enough data" (then ``reason`` says what is
    missing and the baseline may be absent). ``baseline_revision_id`` is the newest baseline
    revision; ``baseline_revisions`` how many were pooled.
    """

    __tablename__ = "detection"
    __table_args__ = (
        UniqueConstraint("series_id", "revision_id", "method"),
        # every store looks for the component's suspected changes: few rows among many
        Index(
            "ix_detection_suspected",
            "series_id",
            postgresql_where=text("confirmation = 'suspected'"),
        ),
    )
    id: Mapped[int] = mapped_column(primary_key=True)
    series_id: Mapped[int] = mapped_column(ForeignKey("series.id"), index=True)
    revision_id: Mapped[int] = mapped_column(ForeignKey("revision.id"), index=True)
    baseline_revision_id: Mapped[int | None] = mapped_column(
        ForeignKey("revision.id"), default=None
    )
    regression_id: Mapped[int | None] = mapped_column(
        ForeignKey("regression.id", ondelete="SET NULL"), index=True, default=None
    )
    #: the configuration it was judged by (None: judged before 0030 kept it)
    config_id: Mapped[int | None] = mapped_column(
        ForeignKey("judging_config.id"), index=True, default=None
    )
    series: Mapped[Series] = relationship()
    revision: Mapped[Revision] = relationship(foreign_keys=[revision_id])
    baseline_revision: Mapped[Revision | None] = relationship(foreign_keys=[baseline_revision_id])


class Reanalysis(Base):
    """The latest re-analysis of a component's whole history, with its progress.

    A re-analysis is split by series into ``parts`` (`redline.worker.reanalysis`), each judging
    every revision of the ``revisions`` planned; ``run`` tells one re-analysis from the next (a
    part of a superseded run stops), ``parts_done`` which parts have judged everything, and
    ``stored`` how many revisions the finishing step stored in order. Progress: ``done`` of
    ``total`` units, one per revision and part, and one per revision stored."""

    __tablename__ = "reanalysis"
    component_id: Mapped[int] = mapped_column(ForeignKey("component.id"), primary_key=True)
    state: Mapped[str] = mapped_column(String(20), default="queued")  # running, done, failed
    total: Mapped[int] = mapped_column(Integer, default=0)
    done: Mapped[int] = mapped_column(Integer, default=0)
    error: Mapped[str] = mapped_column(Text, default="")
    requested: Mapped[datetime] = mapped_column(default=utcnow)
    started: Mapped[datetime | None] = mapped_column(default=None)
    finished: Mapped[datetime | None] = mapped_column(default=None)
    run: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    parts: Mapped[int] = mapped_column(Integer, default=1, server_default="1")
    #: read only where it is used (a part's start, the finishing step's): it holds every revision
    revisions: Mapped[list[int]] = mapped_column(
        JSON, default=list, server_default="[]", deferred=True
    )
    parts_done: Mapped[list[int]] = mapped_column(JSON, default=list, server_default="[]")
    stored: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    #: the finishing step met a revision whose executions changed since its parts judged it:
    #: from there on it judges each revision again from the database, as detection does
    from_database: Mapped[bool] = mapped_column(Boolean, default=False, server_default="false")
    #: the detection configuration as the run was planned, which its parts and finishing step
    #: judge by however the component's changes meanwhile (None: planned before 0019)
    config: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)


class StagedDetection(VerdictColumns, Base):
    """A re-analysis part's verdict (the columns of a `Detection`), kept until the finishing
    step stores its revision's verdicts in revision order (`redline.worker.reanalysis`)."""

    __tablename__ = "staged_detection"
    __table_args__ = (Index("ix_staged_detection_revision", "component_id", "run", "revision_id"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int] = mapped_column(ForeignKey("component.id", ondelete="CASCADE"))
    run: Mapped[int] = mapped_column(Integer)
    part: Mapped[int] = mapped_column(Integer)
    series_id: Mapped[int] = mapped_column(Integer)
    revision_id: Mapped[int] = mapped_column(Integer)
    baseline_revision_id: Mapped[int | None] = mapped_column(Integer, default=None)


class StagedRevision(Base):
    """That a re-analysis part judged a revision, and from which executions ("kept": its samples
    are gone and its stored verdicts stand), written with its `StagedDetection` rows."""

    __tablename__ = "staged_revision"
    component_id: Mapped[int] = mapped_column(
        ForeignKey("component.id", ondelete="CASCADE"), primary_key=True
    )
    run: Mapped[int] = mapped_column(Integer, primary_key=True)
    # before the part: the finishing step looks a batch of revisions up across the parts
    revision_id: Mapped[int] = mapped_column(Integer, primary_key=True)
    part: Mapped[int] = mapped_column(Integer, primary_key=True)
    executions: Mapped[str] = mapped_column(Text)
    #: the revision's `Revision.inputs` when the part began (null: staged before it was kept)
    inputs: Mapped[int | None] = mapped_column(Integer, default=None)
