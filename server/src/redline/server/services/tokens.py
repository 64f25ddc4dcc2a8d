"""API tokens: issue, authenticate, list, revoke."""

from __future__ import annotations

from collections.abc import Sequence

from pydantic import TypeAdapter, ValidationError
from redline.server.core.security import hash_token, new_token, parse_scopes, pool_or_host
from redline.server.models import ApiToken, Component, utcnow
from redline.server.schemas.fields import Word, escaped, path_segment
from redline.server.schemas.tokens import TOKEN_NAME_CHARS
from redline.server.services.errors import BadRequest, Conflict, NotFound
from sqlalchemy import func, select
from sqlalchemy.orm import Session

TOKEN_NAME_LOCK = 0x544B  # "TK": the first key of the advisory lock an issuer takes per name
_LABELS = TypeAdapter(list[Word])


def authenticate(session: Session, secret: str, stamp: bool = True) -> ApiToken | None:
    """The live token with this secret, its last use stamped (when ``stamp``); None when
    unknown or revoked."""
    token = session.scalar(
        select(ApiToken).where(ApiToken.token_hash == hash_token(secret), ~ApiToken.revoked)
    )
    if token is not None and stamp:
        token.last_used = utcnow()
        session.commit()
    return token


def issue_token(
    session: Session,
    name: str,
    scopes: str | list[str],
    host: str | None = None,
    labels: str | Sequence[str] = (),
    components: str | Sequence[str] = (),
) -> tuple[ApiToken, str]:
    """A new token and its secret (shown once: only its hash is stored); a token with the
    ``agent`` scope must be bound to ``host`` (a name, or ``PREFIX*``: a pool of hosts whose
    names start so), and only it has one, and ``labels``, the ones its host may register with
    (none: it runs the jobs of components that ask for no label); a ci, triage or agent token
    may be bound to ``components``, the only ones it acts on (none: every one). Labels and
    components are lists, or comma-separated as the CLI and the settings form give them. One
    live token per name. The one way tokens are made (API, CLI and the settings page)."""
    try:
        parsed = parse_scopes(scopes)
        if host:
            pool_or_host(host)
        kept = sorted(set(_LABELS.validate_python(_listed(labels))))
    except ValidationError as exc:
        problem = exc.errors()[0]
        raise BadRequest(f"labels: {problem['input']!r}: {problem['msg']}") from None
    except ValueError as exc:
        raise BadRequest(str(exc)) from None
    acting_on = _components(session, parsed, _listed(components))
    try:  # a CR/LF made `redline token list` print a second row; a '/' no URL could revoke
        path_segment(name)
    except ValueError as exc:
        raise BadRequest(f"a token's name '{escaped(name[:80])}' {exc}") from None
    for field, given, most in (("name", name, TOKEN_NAME_CHARS), ("host", host or "", 200)):
        if len(given) > most:  # the settings form's too, which no schema checks
            raise BadRequest(f"a token's {field} is at most {most} characters")
    if not name.strip():  # `redline token create ""` made one; the API took "   "
        raise BadRequest("a token's name must not be empty or blank: name who it is for")
    if name.isascii() and name.isdecimal():  # `revoke_token` reads such a name as an id first
        raise BadRequest(
            f"a token's name {name[:80]!r} must not be digits only: it would read as a token's "
            "id (revoke by id, GET /api/v1/tokens); add a letter, as in 'ci-2026'"
        )
    if "agent" in parsed and not host:
        raise BadRequest(
            "an agent token acts for one host, or a pool of hosts named alike: name it (host, "
            "or --host HOST, or --host 'PREFIX*'); a token that may act as any host is not issued"
        )
    if host and "agent" not in parsed:
        raise BadRequest(f"host {host!r} binds an agent token; this token has no 'agent' scope")
    if kept and "agent" not in parsed:
        raise BadRequest(f"labels {kept} are an agent token's; this token has no 'agent' scope")
    # one issuer per name at a time, so two at once cannot both find no live token
    session.execute(select(func.pg_advisory_xact_lock(TOKEN_NAME_LOCK, func.hashtext(name))))
    live = session.scalar(select(ApiToken).where(ApiToken.name == name, ~ApiToken.revoked))
    if live is not None:
        raise Conflict(f"a live token named {name!r} exists; revoke it first")
    secret = new_token()
    token = ApiToken(
        name=name,
        token_hash=hash_token(secret),
        scopes=parsed,
        host=host,
        labels=kept,
        components=acting_on,
    )
    session.add(token)
    session.commit()
    return token, secret


def _listed(given: str | Sequence[str]) -> list[str]:
    """A list as given, or comma-separated text's items."""
    if isinstance(given, str):
        return [item.strip() for item in given.split(",") if item.strip()]
    return list(given)


#: the scopes whose acts are a component's: reporting its revisions, triaging its
#: regressions, running its jobs and reporting its run-time faults
BINDABLE = ("ci", "triage", "agent")


def _components(session: Session, scopes: list[str], names: list[str]) -> list[str]:
    """The components a token of ``scopes`` is bound to, each one that exists; `BadRequest`
    naming the first that does not, or when the token's scopes act on no component alone."""
    if not names:
        return []
    if "admin" in scopes or not set(scopes) & set(BINDABLE):
        raise BadRequest(
            f"components bind a {', '.join(BINDABLE)} token to what it acts on; a token with "
            f"the scopes {', '.join(scopes)} reads or administers every component"
        )
    known = set(session.scalars(select(Component.name).where(Component.name.in_(names))))
    for name in names:
        if name not in known:
            raise BadRequest(f"components: unknown component {escaped(name)[:80]!r}")
    return sorted(set(names))


def acts_on(bound: Sequence[str], component: str) -> bool:
    """Whether a token bound to the components ``bound`` (or a session it opened) may act on
    ``component``: bound to none (every one) or to it."""
    return not bound or component in bound


def list_tokens(session: Session) -> list[ApiToken]:
    return list(session.scalars(select(ApiToken).order_by(ApiToken.id)))


def revoke_token(session: Session, name_or_id: str) -> list[ApiToken]:
    """Revoke the token with this id, or every live token with this name; NotFound otherwise.
    A number is a live token's id first, then a name (an older Redline let tokens be named
    "2026"; a review found id 5 revoked before answer for a live token named "5")."""
    tokens = []
    numeral = name_or_id.isascii() and name_or_id.isdecimal()  # '²' is a digit, not a number
    if numeral and int(name_or_id) < 2**31:  # past that, no id: a name
        by_id = select(ApiToken).where(ApiToken.id == int(name_or_id), ~ApiToken.revoked)
        tokens = list(session.scalars(by_id))
    if not tokens:
        by_name = select(ApiToken).where(ApiToken.name == name_or_id, ~ApiToken.revoked)
        tokens = list(session.scalars(by_name))
    if not tokens:
        raise NotFound(f"no live token named or numbered {name_or_id!r}")
    for token in tokens:
        token.revoked = True
    session.commit()
    return tokens
