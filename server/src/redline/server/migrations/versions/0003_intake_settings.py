"""intake: component settings (host labels, webhook secret, normalized repository), revision
branch/message/commit time, job labels, token host, execution pruning, summary quantile sketch

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-22 04:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("component", sa.Column("repo_key", sa.Text(), nullable=False, server_default=""))
    op.add_column(
        "component", sa.Column("host_labels", sa.JSON(), nullable=False, server_default="[]")
    )
    op.add_column("component", sa.Column("webhook_secret", sa.Text(), nullable=True))
    op.add_column(
        "component", sa.Column("description", sa.Text(), nullable=False, server_default="")
    )
    op.create_index("ix_component_repo_key", "component", ["repo_key"])
    _backfill_repo_keys()
    op.add_column(
        "revision", sa.Column("branch", sa.String(200), nullable=False, server_default="")
    )
    op.add_column("revision", sa.Column("message", sa.Text(), nullable=False, server_default=""))
    op.add_column("revision", sa.Column("committed_at", sa.DateTime(timezone=True), nullable=True))
    op.add_column("job", sa.Column("labels", sa.JSON(), nullable=False, server_default="[]"))
    op.add_column("api_token", sa.Column("host", sa.String(200), nullable=True))
    op.add_column("execution", sa.Column("pruned_at", sa.DateTime(timezone=True), nullable=True))
    op.add_column("summary", sa.Column("sketch", sa.JSON(), nullable=True))


def _backfill_repo_keys() -> None:
    from redline.server.services.repos import repo_key

    connection = op.get_bind()
    rows = connection.execute(sa.text("SELECT id, repo FROM component")).all()
    for ident, repo in rows:
        connection.execute(
            sa.text("UPDATE component SET repo_key = :key WHERE id = :id"),
            {"key": repo_key(repo), "id": ident},
        )


def downgrade() -> None:
    op.drop_column("summary", "sketch")
    op.drop_column("execution", "pruned_at")
    op.drop_column("api_token", "host")
    op.drop_column("job", "labels")
    op.drop_column("revision", "committed_at")
    op.drop_column("revision", "message")
    op.drop_column("revision", "branch")
    op.drop_index("ix_component_repo_key", table_name="component")
    op.drop_column("component", "description")
    op.drop_column("component", "webhook_secret")
    op.drop_column("component", "host_labels")
    op.drop_column("component", "repo_key")
