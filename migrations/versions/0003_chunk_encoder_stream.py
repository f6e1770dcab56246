"""Frame chunks may keep the encoder stream on stamps of its own (multi-rate recordings).

Adds three nullable columns to ``chunks``: ``n_q`` and ``t_q`` (the encoder stamps; NULL in a
single-clock chunk, whose ``q`` stays on ``t``) and ``qd`` (joint velocities as the encoders reported
them; NULL when they report none). Existing chunks keep working unchanged: they are single-clock.
The new blobs are stored uncompressed on PostgreSQL, like the others (0002).

Downgrading deletes the multi-rate chunks (the old schema cannot hold two clocks) and drops the columns.

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-01
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | Sequence[str] | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BLOBS = ("t_q", "qd")


def upgrade() -> None:
    with op.batch_alter_table("chunks") as batch:
        batch.add_column(sa.Column("n_q", sa.Integer(), nullable=True))
        batch.add_column(sa.Column("t_q", sa.LargeBinary(), nullable=True))
        batch.add_column(sa.Column("qd", sa.LargeBinary(), nullable=True))
    if op.get_bind().dialect.name == "postgresql":
        for col in BLOBS:
            op.execute(f"ALTER TABLE chunks ALTER COLUMN {col} SET STORAGE EXTERNAL")


def downgrade() -> None:
    op.execute("DELETE FROM chunks WHERE t_q IS NOT NULL")
    with op.batch_alter_table("chunks") as batch:
        batch.drop_column("qd")
        batch.drop_column("t_q")
        batch.drop_column("n_q")
