"""Chunks keep a frame batch's extra channels (foot forces) beside its IMU samples.

Adds ``chunks.channel_names`` (the channels' names, JSON) and ``chunks.channels`` (their samples on
the IMU stamps ``t``, float64 blob, ``n`` x channels). Both stay NULL for chunks without channels,
which is every chunk written before. Downgrading drops them: the windows lose the channels, the
floating-base checks that read foot forces then report them undetermined.

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-03
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009"
down_revision: str | Sequence[str] | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("chunks", sa.Column("channel_names", sa.JSON(), nullable=True))
    op.add_column("chunks", sa.Column("channels", sa.LargeBinary(), nullable=True))


def downgrade() -> None:
    # a plain DROP COLUMN (SQLite 3.35+), not a batch copy of the frames' table
    op.drop_column("chunks", "channels")
    op.drop_column("chunks", "channel_names")
