"""API tokens: stored only as their hash."""

from __future__ import annotations

from datetime import datetime

from redline.server.models.base import Base, utcnow
from sqlalchemy import (
    JSON,
    Boolean,
    String,
)
from sqlalchemy.orm import Mapped, mapped_column


class ApiToken(Base):
    __tablename__ = "api_token"
    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    scopes: Mapped[list[str]] = mapped_column(JSON)
    created: Mapped[datetime] = mapped_column(default=utcnow)
    last_used: Mapped[datetime | None] = mapped_column(default=None)
    revoked: Mapped[bool] = mapped_column(Boolean, default=False)
    host: Mapped[str | None] = mapped_column(String(200), default=None)  # an agent token's host
