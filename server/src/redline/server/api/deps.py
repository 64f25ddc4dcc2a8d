"""FastAPI dependencies: settings, a database session, and the caller's token with its scope."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from redline.server.core.config import Settings
from redline.server.core.security import PAGE_READERS, READERS, acts_for, grants
from redline.server.db import session_factory
from redline.server.models import ApiToken
from redline.server.services.signin import SESSION_COOKIE, current
from redline.server.services.tokens import acts_on, authenticate
from sqlalchemy.orm import Session

_bearer = HTTPBearer(auto_error=False, description="a Redline API token")


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


SettingsDep = Annotated[Settings, Depends(get_settings)]


def get_session(settings: SettingsDep) -> Iterator[Session]:
    with session_factory(settings.database_url)() as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session)]


def _checked(session: Session, secret: str | None, *scopes: str, stamp: bool = True) -> ApiToken:
    """The live token ``secret`` names, granting one of ``scopes`` (its last use stamped
    unless not ``stamp``); 401 or 403 otherwise."""
    unauthorized = {"WWW-Authenticate": "Bearer"}
    if not secret:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED, "missing bearer token", headers=unauthorized
        )
    token = authenticate(session, secret, stamp=stamp)
    if token is None:
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED, "invalid or revoked token", headers=unauthorized
        )
    if not any(grants(token.scopes, scope) for scope in scopes):
        wanted = " or ".join(repr(scope) for scope in scopes)
        raise HTTPException(
            status.HTTP_403_FORBIDDEN, f"token {token.name!r} lacks the {wanted} scope"
        )
    return token


def _bearer_secret(credentials: HTTPAuthorizationCredentials | None) -> str | None:
    if credentials is None or credentials.scheme.lower() != "bearer":
        return None
    return credentials.credentials


def require(scope: str) -> Callable[..., ApiToken]:
    """A dependency admitting only a live token granting ``scope`` (``admin`` grants all)."""

    def check(
        session: SessionDep,
        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
    ) -> ApiToken:
        return _checked(session, _bearer_secret(credentials), scope)

    def before_body(request: Request) -> None:
        """The same check, which `JsonRoute` makes before it reads a body: FastAPI reads and
        parses it before any dependency, and an audit's made-up token had 32 MiB of JSON parsed
        on the event loop before its 401."""
        scheme, _, secret = request.headers.get("authorization", "").partition(" ")
        given = secret.strip() if scheme.lower() == "bearer" else None
        with session_factory(get_settings(request).database_url)() as session:
            _checked(session, given, scope, stamp=False)  # `check` stamps it once

    check.before_body = before_body  # type: ignore[attr-defined]
    return check


#: One instance, so that a router's dependency and a handler's parameter share a single check.
require_agent = require("agent")
AgentToken = Annotated[ApiToken, Depends(require_agent)]
require_ci = require("ci")
CiToken = Annotated[ApiToken, Depends(require_ci)]
require_triage = require("triage")
TriageToken = Annotated[ApiToken, Depends(require_triage)]


def ensure_own_host(token: ApiToken, host: str) -> None:
    """An agent token acts for the host it is bound to only, or one of its pool (``PREFIX*``:
    the hosts whose names start so), 403 otherwise. One bound to no host (issued before that
    was refused) acts for none; an admin token without a host acts for any."""
    if token.host is None and "admin" in token.scopes:
        return
    if token.host is None:
        raise HTTPException(
            status.HTTP_403_FORBIDDEN,
            f"token {token.name!r} is bound to no host, so it may act for none: "
            "revoke it and create one with --host HOST",
        )
    if not acts_for(token.host, host):
        raise HTTPException(
            status.HTTP_403_FORBIDDEN,
            f"token {token.name!r} belongs to host {token.host!r}, not {host!r}",
        )


def token_labels(token: ApiToken) -> list[str] | None:
    """The host labels an agent token was given (an admin's to give); None for an admin
    token without a host, which may claim any."""
    if token.host is None and "admin" in token.scopes:
        return None
    return list(token.labels or [])


def ensure_own_labels(token: ApiToken, labels: list[str]) -> None:
    """An agent token's host registers with the labels an admin gave the token, or fewer, 403
    otherwise: a component's ``host_labels`` say which hosts run its jobs, and a host naming
    its own would lease any component's."""
    allowed = token_labels(token)
    foreign = sorted(set(labels) - set(allowed)) if allowed is not None else []
    if foreign:
        raise HTTPException(
            status.HTTP_403_FORBIDDEN,
            f"token {token.name!r} may register its host with the labels "
            f"{', '.join(allowed or []) or 'none'}, not {', '.join(foreign)}: an admin gives a "
            "host its labels (revoke this token and create one with --labels A,B)",
        )


def ensure_component(token: ApiToken, component: str) -> None:
    """A token bound to components acts on those only, 403 otherwise (an admin binds it:
    ``redline token create ... --components A,B``)."""
    if not acts_on(token.components or [], component):
        raise HTTPException(
            status.HTTP_403_FORBIDDEN,
            f"token {token.name!r} acts on the components {', '.join(token.components)} only, "
            f"not {component[:200]!r}",
        )


READ_COOKIE = "redline_token"


def reader(*scopes: str) -> Callable[..., None]:
    """A dependency for reading: open unless ``REDLINE_READ_ACCESS=token``; then a token with
    one of ``scopes`` is needed, as a bearer header, the ``redline_token`` cookie or ``?token=``
    (for the browser UI), or a signed-in session of the pages whose scopes grant one of them
    (a ci session reads verdicts only, as its token does). Open or not, a token that is
    given as a bearer header or ``?token=`` must be live (401 otherwise): a mistyped CI secret
    is refused, never ignored. (A stale cookie is not refused where reading is open: the
    browser, not the caller, sends it.)"""

    def check(
        request: Request,
        session: SessionDep,
        settings: SettingsDep,
        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
    ) -> None:
        if settings.read_access != "token":
            given = _bearer_secret(credentials) or request.query_params.get("token")
            if given and authenticate(session, given) is None:
                raise HTTPException(
                    status.HTTP_401_UNAUTHORIZED,
                    "invalid or revoked token",
                    headers={"WWW-Authenticate": "Bearer"},
                )
            return
        signed_in = current(session, request.cookies.get(SESSION_COOKIE))
        # a session reads what its scopes read, no more (a ci session: verdicts only)
        if signed_in is not None and any(grants(signed_in.scopes, s) for s in scopes):
            return
        secret = (
            _bearer_secret(credentials)
            or request.cookies.get(READ_COOKIE)
            or request.query_params.get("token")
        )
        if signed_in is not None and not secret:
            wanted = " or ".join(repr(scope) for scope in scopes)
            raise HTTPException(
                status.HTTP_403_FORBIDDEN,
                f"signed in as {signed_in.who!r}, which lacks the {wanted} scope: sign in "
                "with a token or user that has it",
            )
        _checked(session, secret, *scopes)

    return check


#: what Redline stored: for readers, and for those who triage what they read
READ = [Depends(reader(*PAGE_READERS))]
#: a revision's verdict: what a CI job, holding its `ci` token, waits for
VERDICT_READ = [Depends(reader(*READERS))]
