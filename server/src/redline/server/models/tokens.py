"""API tokens, people who sign in to the pages, and their sessions: secrets stored only as
hashes."""

from __future__ import annotations

from datetime import datetime

from redline.server.models.base import Base, utcnow
from sqlalchemy import (
    JSON,
    Boolean,
    ForeignKey,
    String,
    Text,
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
    # an agent token's labels: those its host may register with (an admin's to give)
    labels: Mapped[list[str]] = mapped_column(JSON, default=list)
    # the components a ci, triage or agent token acts on (an admin's to give); none: every one
    components: Mapped[list[str]] = mapped_column(JSON, default=list)


class User(Base):
    """Someone who signs in to the pages with a password (`redline user create`)."""

    __tablename__ = "web_user"
    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    password_hash: Mapped[str] = mapped_column(Text)  # scrypt, with its salt and parameters
    scopes: Mapped[list[str]] = mapped_column(JSON)
    created: Mapped[datetime] = mapped_column(default=utcnow)
    disabled: Mapped[bool] = mapped_column(Boolean, default=False)


class WebSession(Base):
    """A signed-in browser: the cookie holds the secret, stored here as its hash, with the
    form token (CSRF) every form of the session must carry."""

    __tablename__ = "web_session"
    id: Mapped[int] = mapped_column(primary_key=True)
    secret_hash: Mapped[str] = mapped_column(String(64), unique=True)
    who: Mapped[str] = mapped_column(String(200))  # a user's name, or "token <name>"
    #: what opened it, one of the two: revoked or disabled, it ends (`signin.current`)
    token_id: Mapped[int | None] = mapped_column(
        ForeignKey("api_token.id", ondelete="CASCADE"), index=True, default=None
    )
    user_id: Mapped[int | None] = mapped_column(
        ForeignKey("web_user.id", ondelete="CASCADE"), index=True, default=None
    )
    scopes: Mapped[list[str]] = mapped_column(JSON)
    csrf: Mapped[str] = mapped_column(String(64))
    created: Mapped[datetime] = mapped_column(default=utcnow)
    expires: Mapped[datetime] = mapped_column()
    #: not stored: the components its token is bound to, as `signin.current` finds them now
    components: tuple[str, ...] = ()
