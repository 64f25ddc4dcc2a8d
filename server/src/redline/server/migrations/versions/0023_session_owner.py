"""A browser session names the token or the user it was opened by, so that revoking the one or
disabling the other ends it

Revision ID: 0023
Revises: 0022
Create Date: 2026-11-29 08:50:00

A security review signed in with an admin token, revoked the token, and the session it had
opened still made a new admin token for up to 7 days. Sessions opened before this have no
owner to check and are ended: their people sign in again.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0023"
down_revision = "0022"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.execute("DELETE FROM web_session")
    for column, table in (("token_id", "api_token"), ("user_id", "web_user")):
        op.add_column("web_session", sa.Column(column, sa.Integer(), nullable=True))
        op.create_foreign_key(
            f"web_session_{column}_fkey",
            "web_session",
            table,
            [column],
            ["id"],
            ondelete="CASCADE",
        )
        op.create_index(f"ix_web_session_{column}", "web_session", [column])


def downgrade() -> None:
    for column in ("token_id", "user_id"):
        op.drop_index(f"ix_web_session_{column}", "web_session")
        op.drop_constraint(f"web_session_{column}_fkey", "web_session", type_="foreignkey")
        op.drop_column("web_session", column)
