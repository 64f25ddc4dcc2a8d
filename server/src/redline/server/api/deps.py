"""FastAPI dependencies: settings, a database session, and the caller's token with its scope."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from redline.server.core.config import Settings
from redline.server.core.security import grants
from redline.server.db import session_factory
from redline.server.models import ApiToken
from redline.server.services.tokens import authenticate
from sqlalchemy.orm import Session

_bearer = HTTPBearer(auto_error=False, description="a Redline API token")


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


SettingsDep = Annotated[Settings, Depends(get_settings)]


def get_session(settings: SettingsDep) -> Iterator[Session]:
    with session_factory(settings.database_url)() as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session)]


def require(scope: str) -> Callable[..., ApiToken]:
    """A dependency admitting only a live token granting ``scope`` (``admin`` grants all)."""

    def check(
        session: SessionDep,
        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
    ) -> ApiToken:
        unauthorized = {"WWW-Authenticate": "Bearer"}
        if credentials is None or credentials.scheme.lower() != "bearer":
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "missing bearer token",
                                headers=unauthorized)
        token = authenticate(session, credentials.credentials)
        if token is None:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "invalid or revoked token",
                                headers=unauthorized)
        if not grants(token.scopes, scope):
            raise HTTPException(status.HTTP_403_FORBIDDEN,
                                f"token {token.name!r} lacks the {scope!r} scope")
        return token

    return check
