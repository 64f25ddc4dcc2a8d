"""Tables of alerting: who wants to hear about which changes (subscriptions), what each was told
(alerts, and the changes they covered), and the outbox every message leaves through
(deliveries: webhooks, mails, commit statuses, with their attempts)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from redline.server.models.base import Base, utcnow
from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import Mapped, mapped_column


class Subscription(Base):
    """Someone to tell about a component's changes (``component_id`` None: every component's).

    ``kind`` is email (``address``) or webhook (``url``, ``secret``, ``format``). The filters:
    ``counters`` (series counters or driver metrics; empty: all), ``direction`` (regression,
    improvement, any), ``min_effect`` (relative, e.g. 0.05), ``confirmed_only``; ``delivery`` is
    immediate or digest (one message a day).
    """

    __tablename__ = "subscription"
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int | None] = mapped_column(
        ForeignKey("component.id", ondelete="CASCADE"), index=True, default=None
    )
    kind: Mapped[str] = mapped_column(String(20))
    address: Mapped[str] = mapped_column(Text, default="")
    url: Mapped[str] = mapped_column(Text, default="")
    secret: Mapped[str] = mapped_column(Text, default="")
    format: Mapped[str] = mapped_column(String(20), default="redline")
    counters: Mapped[list[str]] = mapped_column(JSON, default=list)
    direction: Mapped[str] = mapped_column(String(20), default="regression")
    min_effect: Mapped[float] = mapped_column(Float, default=0.0)
    confirmed_only: Mapped[bool] = mapped_column(Boolean, default=True)
    delivery: Mapped[str] = mapped_column(String(20), default="immediate")
    digest_sent: Mapped[datetime | None] = mapped_column(default=None)
    created: Mapped[datetime] = mapped_column(default=utcnow)
    updated: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)


class Alert(Base):
    """What one subscription was told (or, for a digest, will be told) about one regression,
    about one revision's improvements (``regression_id`` None, ``revision_id`` set), or about a
    fault `redline watch` saw at run time (``runtime_alarm_id`` set: told once per subscription)."""

    __tablename__ = "alert"
    __table_args__ = (
        UniqueConstraint(
            "subscription_id", "runtime_alarm_id", name="uq_alert_subscription_runtime_alarm"
        ),
    )
    id: Mapped[int] = mapped_column(primary_key=True)
    subscription_id: Mapped[int] = mapped_column(
        ForeignKey("subscription.id", ondelete="CASCADE"), index=True
    )
    regression_id: Mapped[int | None] = mapped_column(
        ForeignKey("regression.id", ondelete="SET NULL"), index=True, default=None
    )
    revision_id: Mapped[int | None] = mapped_column(
        ForeignKey("revision.id", ondelete="SET NULL"), default=None
    )
    runtime_alarm_id: Mapped[int | None] = mapped_column(
        ForeignKey("runtime_alarm.id", ondelete="CASCADE"), default=None
    )
    #: regression, regression.updated, improvement, runtime_fault, runtime_fault.over
    kind: Mapped[str] = mapped_column(String(30))
    body: Mapped[dict[str, Any]] = mapped_column(JSON)  # the alert's part of a message
    delivery_id: Mapped[int | None] = mapped_column(
        ForeignKey("delivery.id", ondelete="SET NULL"), index=True, default=None
    )
    created: Mapped[datetime] = mapped_column(default=utcnow)


class AlertedChange(Base):
    """A change (series x revision) a subscription was told about: never told again, whatever
    re-analysis, regrouping or confirmation does to the regression around it."""

    __tablename__ = "alerted_change"
    subscription_id: Mapped[int] = mapped_column(
        ForeignKey("subscription.id", ondelete="CASCADE"), primary_key=True
    )
    series_id: Mapped[int] = mapped_column(ForeignKey("series.id"), primary_key=True)
    revision_id: Mapped[int] = mapped_column(ForeignKey("revision.id"), primary_key=True)
    alert_id: Mapped[int] = mapped_column(ForeignKey("alert.id", ondelete="CASCADE"), index=True)


class RegressionTold(Base):
    """What a subscription was last told of a regression's confirmation, once anything of it
    was sent (an immediate alert, a digest that carried it, a follow-up): a later confirmation
    that differs is followed up (`redline.worker.follow_ups`)."""

    __tablename__ = "regression_told"
    subscription_id: Mapped[int] = mapped_column(
        ForeignKey("subscription.id", ondelete="CASCADE"), primary_key=True
    )
    regression_id: Mapped[int] = mapped_column(
        ForeignKey("regression.id", ondelete="CASCADE"), primary_key=True, index=True
    )
    confirmation: Mapped[str] = mapped_column(String(20))


class Delivery(Base):
    """One message in the outbox: a webhook call, a mail or a commit status.

    ``uid`` goes out with it (the X-Redline-Delivery header, the mail's Message-ID), so a
    receiver that got it before a worker died can tell the retry apart. States: pending (due at
    ``next_try``), sending (leased until ``lease_until``), delivered, failed (no tries left),
    superseded (a commit status a newer one of its revision replaced before it was sent:
    `redline.worker.statuses`).
    """

    __tablename__ = "delivery"
    __table_args__ = (
        Index(
            "ix_delivery_due",
            "next_try",
            postgresql_where=text("state IN ('pending', 'sending')"),
        ),
    )
    id: Mapped[int] = mapped_column(primary_key=True)
    uid: Mapped[str] = mapped_column(String(36), unique=True)
    #: what makes it once-only where no alert row does (a commit status: revision and state)
    key: Mapped[str | None] = mapped_column(String(200), unique=True, default=None)
    subscription_id: Mapped[int | None] = mapped_column(
        ForeignKey("subscription.id", ondelete="CASCADE"), index=True, default=None
    )
    component_id: Mapped[int | None] = mapped_column(
        ForeignKey("component.id", ondelete="CASCADE"), index=True, default=None
    )
    kind: Mapped[str] = mapped_column(String(20))  # webhook, email, status
    event: Mapped[str] = mapped_column(String(40))
    #: what to send: the JSON body, or the mail's subject and parts, or the status call
    payload: Mapped[dict[str, Any]] = mapped_column(JSON)
    state: Mapped[str] = mapped_column(String(20), default="pending", index=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    last_error: Mapped[str] = mapped_column(Text, default="")
    next_try: Mapped[datetime] = mapped_column(default=utcnow)
    lease_until: Mapped[datetime | None] = mapped_column(default=None)
    created: Mapped[datetime] = mapped_column(default=utcnow)
    delivered: Mapped[datetime | None] = mapped_column(default=None)
