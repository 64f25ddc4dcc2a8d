"""An agent token carries the labels its host may register with

Revision ID: 0031
Revises: 0030
Create Date: 2026-12-06 14:00:00

A host registered with whatever labels it named, and a component's ``host_labels`` (an admin's
setting: which hosts run its jobs) were only as good as every host's word: the holder of any
agent token could claim a component's labels and lease its jobs (a security review's find).
Now an admin gives an agent token its labels (``redline token create ... --labels a,b``) and a
host registers with those or fewer. A token issued before keeps the labels its hosts have
registered with so far, so that no running agent loses its jobs.
"""

from __future__ import annotations

import json

import sqlalchemy as sa
from alembic import op

revision = "0031"
down_revision = "0030"
branch_labels = None
depends_on = None


def _acts_for(bound: str, host: str) -> bool:
    """`redline.server.core.security.acts_for` as it was when this migration was written."""
    if bound.endswith("*"):
        prefix = bound.removesuffix("*")
        return host.startswith(prefix) and host != prefix
    return host == bound


def upgrade() -> None:
    op.add_column(
        "api_token",
        sa.Column("labels", sa.JSON(), nullable=False, server_default=sa.text("'[]'")),
    )
    bind = op.get_bind()
    hosts = bind.execute(sa.text("SELECT name, labels FROM host")).all()
    tokens = bind.execute(sa.text("SELECT id, host FROM api_token WHERE host IS NOT NULL")).all()
    for token_id, bound in tokens:
        labels = sorted(
            {
                str(label)
                for name, claimed in hosts
                if _acts_for(bound, name)
                for label in (json.loads(claimed) if isinstance(claimed, str) else claimed or [])
            }
        )
        if labels:
            bind.execute(
                sa.text("UPDATE api_token SET labels = CAST(:labels AS json) WHERE id = :id"),
                {"labels": json.dumps(labels), "id": token_id},
            )


def downgrade() -> None:
    op.drop_column("api_token", "labels")
