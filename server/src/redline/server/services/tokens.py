"""API tokens: issue, authenticate."""

from __future__ import annotations

from redline.server.core.security import hash_token, new_token, parse_scopes
from redline.server.models import ApiToken, utcnow
from sqlalchemy import select
from sqlalchemy.orm import Session


def create_token(session: Session, name: str, scopes: str | list[str]) -> str:
    """Store a new token (its hash only) and return the secret, which is shown once."""
    secret = new_token()
    session.add(ApiToken(name=name, token_hash=hash_token(secret), scopes=parse_scopes(scopes)))
    session.commit()
    return secret


def authenticate(session: Session, secret: str) -> ApiToken | None:
    """The live token with this secret, its last use stamped; None when unknown or revoked."""
    token = session.scalar(
        select(ApiToken).where(ApiToken.token_hash == hash_token(secret), ~ApiToken.revoked)
    )
    if token is not None:
        token.last_used = utcnow()
        session.commit()
    return token
