"""What was measured: named series, and a summary per execution and series (the raw samples stay
in Parquet beside each recording)."""

from __future__ import annotations

from redline.server.models.base import Base
from sqlalchemy import (
    JSON,
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
