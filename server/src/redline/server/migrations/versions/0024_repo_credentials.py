"""Repository URLs lose the passwords and tokens they carried

Revision ID: 0024
Revises: 0023
Create Date: 2026-11-29 09:00:00

A security review set ``https://ci-bot:TOKEN@github.com/org/private.git`` as a component's
repository: the API and the pages showed the token to every reader, and a host would have put
it on git's command line. Such URLs are refused since; those stored before lose their user
information (an ssh URL keeps its user, which is no secret), in the components and in the
revisions that copied them. Their hosts authenticate with git's credential helper or an ssh key
from then on. The credentials are not kept anywhere, so there is no way back.
"""

from __future__ import annotations

import re

import sqlalchemy as sa
from alembic import op

revision = "0024"
down_revision = "0023"
branch_labels = None
depends_on = None

#: scheme://, then the user information up to its last '@' before the path (a password may
#: hold a raw '@')
_USERINFO = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*://)([^/]*)@")


def without_secret(url: str) -> str:
    """``url`` without its password or token: an ssh URL keeps its user, any other loses its
    user information whole (``https://TOKEN@host`` carries a token as the user)."""
    match = _USERINFO.match(url)
    if match is None:
        return url
    scheme, userinfo = match.groups()
    if scheme.lower() == "ssh://" and ":" not in userinfo:
        return url
    kept = f"{userinfo.split(':', 1)[0]}@" if scheme.lower() == "ssh://" else ""
    return scheme + kept + url[match.end() :]


def upgrade() -> None:
    connection = op.get_bind()
    for table in ("component", "revision"):
        rows = sa.table(table, sa.column("id"), sa.column("repo"))
        found = connection.execute(
            sa.select(rows.c.id, rows.c.repo).where(
                rows.c.repo.regexp_match("^[A-Za-z+.-]+://[^/]*@")
            )
        ).all()
        for ident, repo in found:
            if (kept := without_secret(repo)) != repo:
                connection.execute(rows.update().where(rows.c.id == ident).values(repo=kept))


def downgrade() -> None:
    """Nothing to restore: the credentials were not kept."""
