"""What was measured: named series, and a summary per execution and series (the raw samples stay
in Parquet beside each recording); and the trend charts rendered from them, cached per view."""

from __future__ import annotations

from datetime import datetime

from redline.server.models.base import Base, utcnow
from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    ForeignKey,
    Integer,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import Mapped, mapped_column


class Series(Base):
    __tablename__ = "series"
    __table_args__ = (
        UniqueConstraint("component_id", "case", "phase", "params", "process", "counter"),
    )
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int] = mapped_column(ForeignKey("component.id"), index=True)
    case: Mapped[str] = mapped_column(String(200))
    phase: Mapped[str] = mapped_column(String(200))
    params: Mapped[str] = mapped_column(Text)  # redline.recording.canonical_params
    process: Mapped[str] = mapped_column(String(200))
    counter: Mapped[str] = mapped_column(String(200))


class Summary(Base):
    __tablename__ = "summary"
    __table_args__ = (UniqueConstraint("execution_id", "series_id"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    execution_id: Mapped[int] = mapped_column(ForeignKey("execution.id"), index=True)
    series_id: Mapped[int] = mapped_column(ForeignKey("series.id"), index=True)
    n: Mapped[int] = mapped_column(Integer)
    mean: Mapped[float] = mapped_column(Float)
    std: Mapped[float] = mapped_column(Float)
    min: Mapped[float] = mapped_column(Float)
    p5: Mapped[float] = mapped_column(Float)
    p25: Mapped[float] = mapped_column(Float)
    p50: Mapped[float] = mapped_column(Float)
    p75: Mapped[float] = mapped_column(Float)
    p95: Mapped[float] = mapped_column(Float)
    max: Mapped[float] = mapped_column(Float)
    # quantiles at SKETCH_LEVELS (redline.detect.summary): the distribution in 32 numbers
    sketch: Mapped[list[float] | None] = mapped_column(JSON, default=None)
    #: measured while the host was busy (`redline.recording.disturbance`): charted, never judged,
    #: and left out of the levels confirmation reads (`redline.worker.confirmation`)
    disturbed: Mapped[bool] = mapped_column(Boolean, default=False, server_default="false")


class FigureCache(Base):
    """A trend view's charts (`redline.server.services.dashboard`), valid while the component's
    data version is ``version``; ``view`` is the view's query string."""

    __tablename__ = "figure_cache"
    __table_args__ = (UniqueConstraint("component_id", "view"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    component_id: Mapped[int] = mapped_column(ForeignKey("component.id"), index=True)
    view: Mapped[str] = mapped_column(Text)
    version: Mapped[str] = mapped_column(Text)
    figures: Mapped[str] = mapped_column(Text)  # JSON, safe inside <script>: served as it is
    earlier: Mapped[str | None] = mapped_column(Text, default=None)
    #: what the page says of the charts it left out ('' when none: `trend_view.cut_charts`)
    note: Mapped[str] = mapped_column(Text, default="", server_default="")
    created: Mapped[datetime] = mapped_column(default=utcnow)
