"""Device clock epochs: a robot whose clock went back (a restart) starts a new epoch of frames.

Adds ``robots.epoch`` (the current epoch, 0 for every existing robot) and ``robots.epoch_start_t``
(device time of the first frame of that epoch; NULL until a robot's clock first goes back), and
``chunks.epoch`` (the epoch a chunk was recorded in, 0 for every existing chunk). Existing data is one
epoch per robot, which is what it always was.

Downgrading deletes the chunks of every epoch but each robot's current one (the old schema has a
single timeline per robot) and drops the columns.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | Sequence[str] | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # Plain ALTER TABLE, not a batch (copy and move) table: recreating ``robots`` on SQLite would
    # cascade-delete every row that refers to it. SQLite adds and drops columns in place since 3.35.
    op.add_column("robots", sa.Column("epoch", sa.Integer(), nullable=False, server_default="0"))
    op.add_column("robots", sa.Column("epoch_start_t", sa.Double(), nullable=True))
    op.add_column("chunks", sa.Column("epoch", sa.Integer(), nullable=False, server_default="0"))


def downgrade() -> None:
    op.execute(
        "DELETE FROM chunks "
        "WHERE epoch <> (SELECT robots.epoch FROM robots WHERE robots.id = chunks.robot_id)"
    )
    op.drop_column("chunks", "epoch")
    op.drop_column("robots", "epoch_start_t")
    op.drop_column("robots", "epoch")
