"""revision.committed_at: forget times Python cannot read back (year 10000 in UTC, say)

Earlier versions stored any commit time a request gave; one past 9999-12-31 in UTC made every
read of its component's revisions fail. Such times are not data anyone can use: they are
cleared, and the API now refuses them at the edge.

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-23 04:00:00
"""

from __future__ import annotations

from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # a day's margin on each side: a session time zone may move a time across the year's edge
    op.execute(
        "UPDATE revision SET committed_at = NULL "
        "WHERE committed_at >= '9999-12-31 00:00:00+00' "
        "OR committed_at < '0001-01-02 00:00:00+00'"
    )


def downgrade() -> None:
    pass  # the cleared times were unreadable; there is nothing to restore
