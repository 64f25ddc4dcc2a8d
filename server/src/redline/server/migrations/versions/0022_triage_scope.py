"""Triage has a scope of its own: people who triaged with ``ci`` keep it, pipelines' tokens lose it

Revision ID: 0022
Revises: 0021
Create Date: 2026-11-28 12:40:00

Before, the ``ci`` scope let a pipeline's token set a regression to ignored or fixed, which is
not what its name says. Users (people at the pages) who have ``ci`` are given ``triage``, and so
are their live sessions; API tokens are not: a pipeline that triaged needs a ``triage`` token.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision = "0022"
down_revision = "0021"
branch_labels = None
depends_on = None

users = sa.table("web_user", sa.column("id"), sa.column("name"), sa.column("scopes", sa.JSON))
sessions = sa.table("web_session", sa.column("id"), sa.column("who"), sa.column("scopes", sa.JSON))
tokens = sa.table("api_token", sa.column("id"), sa.column("scopes", sa.JSON))


def _give_triage(table: sa.TableClause, rows: Sequence[sa.Row]) -> None:
    for row in rows:
        if "ci" in row.scopes and "triage" not in row.scopes:
            scopes = sorted({*row.scopes, "triage"})
            op.execute(table.update().where(table.c.id == row.id).values(scopes=scopes))


def upgrade() -> None:
    connection = op.get_bind()
    people = connection.execute(sa.select(users.c.id, users.c.name, users.c.scopes)).all()
    _give_triage(users, people)
    names = {row.name for row in people}
    signed_in = connection.execute(sa.select(sessions.c.id, sessions.c.who, sessions.c.scopes))
    # a pasted token's session is "token <its name>" (a user so named signs in again)
    users_own = [r for r in signed_in.all() if r.who in names and not r.who.startswith("token ")]
    _give_triage(sessions, users_own)


def downgrade() -> None:
    """Before 0022 ``ci`` triaged: people with ``triage`` get ``ci`` back in its place; a token
    loses it (a token left with no scope reads)."""
    connection = op.get_bind()
    for table, instead in ((users, ["ci"]), (sessions, ["ci"]), (tokens, [])):
        for row in connection.execute(sa.select(table.c.id, table.c.scopes)).all():
            if "triage" in row.scopes:
                kept = [scope for scope in row.scopes if scope != "triage"]
                scopes = sorted({*kept, *instead}) or ["read"]
                op.execute(table.update().where(table.c.id == row.id).values(scopes=scopes))
