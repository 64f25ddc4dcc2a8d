"""A token may be bound to components

Revision ID: 0032
Revises: 0031
Create Date: 2026-12-06 17:00:00

A ci token reported revisions of any component, a triage token triaged any component's
regressions, and an agent token reported run-time alerts for any component (security.md's "Not
covered"). An admin may now bind a token to components (``redline token create ... --components
a,b``); a token issued before, or without them, acts on every component as it did.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0032"
down_revision = "0031"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column(
        "api_token",
        sa.Column("components", sa.JSON(), nullable=False, server_default=sa.text("'[]'")),
    )


def downgrade() -> None:
    op.drop_column("api_token", "components")
