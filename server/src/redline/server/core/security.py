"""API tokens: random bearer secrets, stored only as their sha256."""

from __future__ import annotations

import hashlib
import secrets
from collections.abc import Iterable

from redline.server.schemas.fields import host_name

SCOPES = frozenset({"ci", "triage", "agent", "read", "admin"})
#: a person's: every scope but a performance host's
PEOPLE_SCOPES = SCOPES - {"agent"}
#: scopes of someone who may read what Redline stored when reading needs a token
#: (`REDLINE_READ_ACCESS=token`) and sign in to the pages: every one but a host's
READERS = ("read", "ci", "triage")
#: ... and of those who read everything else, the pages too (a `ci` token reads verdicts only)
PAGE_READERS = ("read", "triage")
TOKEN_PREFIX = "rl_"


def new_token() -> str:
    """A fresh bearer token; shown once, never stored in clear."""
    return TOKEN_PREFIX + secrets.token_urlsafe(32)


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def parse_scopes(text: str | list[str], known: Iterable[str] = SCOPES) -> list[str]:
    """Validate a scope list (``"ci,agent"`` or a list) against ``known``; raises ValueError
    naming an unknown one and the known ones."""
    items = text.split(",") if isinstance(text, str) else list(text)
    scopes = sorted({item.strip() for item in items if item.strip()})
    unknown = [scope for scope in scopes if scope not in known]
    if unknown:
        raise ValueError(f"unknown scope {unknown[0]!r}; known: {', '.join(sorted(known))}")
    if not scopes:
        raise ValueError("a token needs at least one scope")
    return scopes


def acts_for(bound: str, host: str) -> bool:
    """Whether an agent token bound to ``bound`` (a host's name, or ``PREFIX*``: a pool of the
    hosts whose names start so, the prefix alone not among them) may act as ``host``."""
    if bound.endswith("*"):
        prefix = bound.removesuffix("*")
        return host.startswith(prefix) and host != prefix
    return host == bound


def pool_or_host(host: str) -> str:
    """``host`` if it can bind an agent token: one name, or a prefix and one '*' at its end;
    raises ValueError otherwise ('*' alone would be any host)."""
    try:
        host_name(host)  # a CR/LF would break `token list`'s rows; a '/' is no machine's name
    except ValueError as exc:
        raise ValueError(f"host {host!r}: {exc}") from None
    if "*" in host.removesuffix("*") or host == "*":
        raise ValueError(
            f"host {host!r}: one host's name, or a pool's prefix with one '*' at its end "
            "('compose-*'); '*' alone would be any host"
        )
    return host


def grants(scopes: list[str], needed: str) -> bool:
    """``admin`` implies every scope."""
    return needed in scopes or "admin" in scopes
