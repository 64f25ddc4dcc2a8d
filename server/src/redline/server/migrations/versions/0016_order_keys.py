"""Order keys again: digits of any script read as numbers, runs of 99 digits or more after the
shorter ones (`redline.server.services.revisions.order_key`)

Revision ID: 0016
Revises: 0015
Create Date: 2026-11-24 17:50:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0016"
down_revision = "0015"
branch_labels = None
depends_on = None

#: revisions read and written back at a time
BATCH = 5000


def upgrade() -> None:
    # the function of the code this migration ships with: it recomputes every key, so a later
    # change of the encoding comes with a migration like this one
    from redline.server.services.revisions import order_key

    bind = op.get_bind()
    revisions = sa.table(
        "revision", sa.column("id", sa.Integer), sa.column("sort_key"), sa.column("order_key")
    )
    last = 0
    while True:
        rows = bind.execute(
            sa.select(revisions.c.id, revisions.c.sort_key, revisions.c.order_key)
            .where(revisions.c.id > last)
            .order_by(revisions.c.id)
            .limit(BATCH)
        ).all()
        if not rows:
            return
        keys = ((ident, order_key(sort_key), stored) for ident, sort_key, stored in rows)
        changed = [{"ident": ident, "key": key} for ident, key, stored in keys if key != stored]
        if changed:
            bind.execute(
                revisions.update()
                .where(revisions.c.id == sa.bindparam("ident"))
                .values(order_key=sa.bindparam("key")),
                changed,
            )
        last = rows[-1][0]


def downgrade() -> None:
    """Nothing to undo: the old keys ordered these sort keys wrongly, and the new order holds
    for every other one."""
