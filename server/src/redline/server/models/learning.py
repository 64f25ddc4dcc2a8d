"""Tables of the resource-usage models (`redline.predict`): models trained from a component's
recordings, with their provenance and metrics, and the run-time alarms `redline watch` reports."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from redline.server.models.base import Base, utcnow
from sqlalchemy import JSON, Boolean, Float, ForeignKey, Integer, String, Text
from sqlalchemy.orm import Mapped, mapped_column


class ResourceModelRow(Base):
    """A model of one component process's CPU and RSS, trained by a worker from executions.

    ``request`` is what was asked (revisions, executions, a test case); ``provenance`` what it
    was made from (executions, steps, groups, features, grid, versions); ``metrics`` per target
    (cross-validated RMSE, its ratio to predicting the mean, the alarm threshold); ``plot`` a
    downsampled measured-and-predicted series for the pages; ``path`` the model file.
    """

    __tablename__ = "resource_model"
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int] = mapped_column(
        ForeignKey("component.id", ondelete="CASCADE"), index=True
    )
    state: Mapped[str] = mapped_column(String(20), default="queued")  # running, done, failed
    error: Mapped[str] = mapped_column(Text, default="")
    request: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    process: Mapped[str] = mapped_column(String(200), default="")
    metrics: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    provenance: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    plot: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    path: Mapped[str] = mapped_column(Text, default="")
    created: Mapped[datetime] = mapped_column(default=utcnow)
    finished: Mapped[datetime | None] = mapped_column(default=None)


class RuntimeAlarm(Base):
    """A resource fault (or its end) that `redline watch` saw on a running component."""

    __tablename__ = "runtime_alarm"
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int] = mapped_column(
        ForeignKey("component.id", ondelete="CASCADE"), index=True
    )
    model_id: Mapped[int | None] = mapped_column(
        ForeignKey("resource_model.id", ondelete="SET NULL"), default=None
    )
    host: Mapped[str] = mapped_column(String(200), default="")
    process: Mapped[str] = mapped_column(String(200), default="")
    target: Mapped[str] = mapped_column(String(50))
    started: Mapped[bool] = mapped_column(Boolean)  # a fault began (True) or ended
    residual: Mapped[float] = mapped_column(Float)
    threshold: Mapped[float] = mapped_column(Float)
    step: Mapped[int] = mapped_column(Integer, default=0)
    at: Mapped[datetime] = mapped_column(default=utcnow)
