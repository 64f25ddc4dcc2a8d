"""Signing in to the pages: people with passwords, or an API token pasted once; sessions.

Passwords are hashed with scrypt (n=2^15, r=8, p=1: about 32 MiB and 50-100 ms a check, OWASP's
recommended floor), with a random salt, stored as ``scrypt$n$r$p$salt$hash``. A session is a
random secret in an HttpOnly, SameSite=Strict cookie, stored only as its sha256, valid for
`SESSION_DAYS`; each session has its own form token (CSRF), which every form posts back. The
sign-in form, which has no session yet, posts back the random token of a cookie of its own
(`SIGNIN_COOKIE`, HttpOnly, SameSite=Strict): another site can neither read nor send it, so it
cannot sign a browser in to an account of its choosing (login CSRF).
A session has the scopes of the user or of the token it was opened with, no more.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import secrets
from dataclasses import dataclass
from datetime import timedelta
from functools import cache

from redline.server.core.security import (
    PAGE_READERS,
    PEOPLE_SCOPES,
    READERS,
    grants,
    hash_token,
    parse_scopes,
)
from redline.server.models import ApiToken, User, WebSession, utcnow
from redline.server.services import tokens
from redline.server.services.errors import BadRequest, Conflict, Forbidden, NotFound
from redline.server.services.tokens import authenticate
from sqlalchemy import delete, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**15, 8, 1
SCRYPT_MEMORY = 64 * 1024 * 1024  # above the 32 MiB these parameters need
MIN_PASSWORD = 12
SESSION_DAYS = 7
SESSION_COOKIE = "redline_session"
#: the sign-in form's token, before any session: a cookie the form posts back (login CSRF)
SIGNIN_COOKIE = "redline_signin"
SIGNIN_HOURS = 24


@cache
def _unknown() -> str:
    """Checked against when a name is unknown: a wrong name costs as long as a wrong password."""
    return hash_password(secrets.token_urlsafe(16))


def _b64(raw: bytes) -> str:
    return base64.b64encode(raw).decode()


def hash_password(password: str) -> str:
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(
        password.encode(), salt=salt, n=SCRYPT_N, r=SCRYPT_R, p=SCRYPT_P, maxmem=SCRYPT_MEMORY
    )
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


def check_password(password: str, stored: str) -> bool:
    try:
        kind, n, r, p, salt, digest = stored.split("$")
        expected = base64.b64decode(digest)
        found = hashlib.scrypt(
            password.encode(),
            salt=base64.b64decode(salt),
            n=int(n),
            r=int(r),
            p=int(p),
            maxmem=SCRYPT_MEMORY,
        )
    except ValueError:
        return False
    return kind == "scrypt" and hmac.compare_digest(found, expected)


def create_user(session: Session, name: str, password: str, scopes: str | list[str]) -> User:
    """A new user; the password must have `MIN_PASSWORD` characters at least."""
    if not name.strip() or len(name) > 200:
        raise BadRequest("a user's name: 1 to 200 characters")
    if len(password) < MIN_PASSWORD:
        raise BadRequest(f"a password needs {MIN_PASSWORD} characters at least")
    given = scopes.split(",") if isinstance(scopes, str) else scopes
    if "agent" in (scope.strip() for scope in given):  # a person never acts as a host
        raise BadRequest(
            "a user's scopes: read, triage, ci or admin; 'agent' is for a host's token"
        )
    try:
        parsed = parse_scopes(scopes, PEOPLE_SCOPES)
    except ValueError as exc:  # names the scopes a person may have, not a host's
        raise BadRequest(str(exc)) from None
    user = User(name=name, password_hash=hash_password(password), scopes=parsed)
    session.add(user)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise Conflict(f"a user named {name!r} exists") from None
    return user


def list_users(session: Session) -> list[User]:
    return list(session.scalars(select(User).order_by(User.name)))


def set_disabled(session: Session, name: str, disabled: bool) -> User:
    """Disable (or enable again) the user called ``name``: a disabled user cannot sign in, and
    their open sessions end at once (`current`); NotFound naming it otherwise."""
    user = session.scalar(select(User).where(User.name == name))
    if user is None:
        raise NotFound(f"no user named {name!r}")
    user.disabled = disabled
    session.commit()
    return user


@dataclass(frozen=True)
class Opened:
    """A new session: the cookie's secret (shown to the browser once) and the session."""

    secret: str
    session: WebSession


def _open(session: Session, opener: ApiToken | User) -> Opened:
    secret = secrets.token_urlsafe(32)
    by_token = isinstance(opener, ApiToken)
    row = WebSession(
        secret_hash=hash_token(secret),
        who=f"token {opener.name}" if by_token else opener.name,
        scopes=list(opener.scopes),
        token_id=opener.id if by_token else None,
        user_id=None if by_token else opener.id,
        csrf=secrets.token_urlsafe(32),
        expires=utcnow() + timedelta(days=SESSION_DAYS),
    )
    session.add(row)
    session.execute(delete(WebSession).where(WebSession.expires < utcnow()))
    session.commit()
    return Opened(secret, row)


def sign_in(
    session: Session, name: str, password: str, token: str, pages_closed: bool = False
) -> Opened:
    """A session for the user with this name and password, or for the API token; a
    `Forbidden` that does not say which part was wrong otherwise. ``pages_closed``: reading
    needs a token (REDLINE_READ_ACCESS=token), so one whose scopes read no page (`ci`: only
    verdicts) is refused here rather than met by a 403 on every page, whose "sign in" led back."""
    if token:
        found = authenticate(session, token.strip())
        if found is None:
            raise Forbidden("that token is not a live API token")
        if not any(grants(list(found.scopes), scope) for scope in READERS):
            raise Forbidden(f"token {found.name!r} is for performance hosts, not for people")
        _reads_pages(f"token {found.name!r}", found.scopes, pages_closed)
        return _open(session, found)
    user = session.scalar(select(User).where(User.name == name, ~User.disabled))
    if not check_password(password, user.password_hash if user else _unknown()) or user is None:
        raise Forbidden("wrong name or password")
    _reads_pages(f"user {user.name!r}", user.scopes, pages_closed)
    return _open(session, user)


def _reads_pages(who: str, scopes: list[str], pages_closed: bool) -> None:
    if pages_closed and not any(grants(list(scopes), scope) for scope in PAGE_READERS):
        raise Forbidden(
            f"{who} reads only revisions' verdicts (scopes {', '.join(scopes)}), not the "
            "pages: sign in with a read or triage token or user"
        )


def current(session: Session, secret: str | None) -> WebSession | None:
    """The live session a cookie's secret opens; None when none, when expired, and when the
    token that opened it is revoked or its user disabled (a review's revoked admin token kept
    its session, which made a new admin token)."""
    if not secret:
        return None
    row = session.scalar(select(WebSession).where(WebSession.secret_hash == hash_token(secret)))
    if row is None or row.expires < utcnow():
        return None
    opener: ApiToken | User | None
    if row.token_id is not None:
        opener = session.get(ApiToken, row.token_id)
        live = opener is not None and not opener.revoked
    else:
        opener = session.get(User, row.user_id) if row.user_id is not None else None
        live = opener is not None and not opener.disabled
    if not live or opener is None:
        return None
    # the request's own copy, which no rollback expires: a form whose write failed rolled the
    # session back, and its error page, reading who is signed in, answered 500 (a review)
    session.expunge(row)
    row.scopes = list(opener.scopes)  # what it may do now, not what it could when it signed in
    row.components = tuple(getattr(opener, "components", None) or ())  # a bound token's
    return row


def sign_out(session: Session, secret: str | None) -> None:
    if secret:
        session.execute(delete(WebSession).where(WebSession.secret_hash == hash_token(secret)))
        session.commit()


def authorize(row: WebSession | None, form_token: str, scope: str) -> str:
    """Who may do what a form asks: the session's name when it is signed in, carries the
    session's form token and grants ``scope``; `Forbidden` naming what is missing otherwise."""
    if row is None:
        raise Forbidden("sign in first")
    check_form(row, form_token)
    if not grants(list(row.scopes), scope):
        raise Forbidden(f"{row.who} lacks the {scope!r} scope")
    return row.who


def acts_on(row: WebSession | None, component: str) -> bool:
    """Whether the session may act on ``component``: opened by a person, or by a token bound
    to no component or to it (`redline.server.services.tokens.acts_on`)."""
    return row is not None and tokens.acts_on(row.components, component)


def ensure_component(row: WebSession | None, component: str) -> None:
    """`Forbidden` unless the session acts on ``component`` (`acts_on`)."""
    if row is None:
        raise Forbidden("sign in first")
    if not acts_on(row, component):
        raise Forbidden(
            f"{row.who} acts on the components {', '.join(row.components)} only, not {component!r}"
        )


def check_form(row: WebSession, form_token: str) -> None:
    """`Forbidden` unless a form posted in session ``row`` carries its form token (CSRF)."""
    if not hmac.compare_digest(form_token.encode(), row.csrf.encode()):
        raise Forbidden("the form's token does not match this session: reload the page")


def signin_token(cookie: str | None) -> str:
    """The sign-in form's token: the browser's own (its `SIGNIN_COOKIE`), else a new one."""
    return cookie if cookie and 32 <= len(cookie) <= 64 else secrets.token_urlsafe(32)


def check_signin_form(cookie: str | None, form_token: str) -> None:
    """`Forbidden` unless the sign-in form posts back the token of the browser's cookie: a form
    posted from another site has neither."""
    if not cookie or not hmac.compare_digest(form_token.encode(), cookie.encode()):
        raise Forbidden("the sign-in form's token does not match: reload this page, then sign in")
