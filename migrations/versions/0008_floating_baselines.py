"""A floating-base robot's baseline, kept so a restart judges on without learning it again.

Adds ``floating_baselines``: per robot, what the floating-base checks learned from one long healthy
window (service/store/floating.py), the rule that took the robot as floating and the window's end.
Downgrading drops the table: the worker learns the baseline again from the next frames.

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-02
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0008"
down_revision: str | Sequence[str] | None = "0007"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    op.create_table(
        "floating_baselines",
        sa.Column("id", BigId, primary_key=True),
        sa.Column(
            "robot_id",
            sa.Integer(),
            sa.ForeignKey("robots.id", ondelete="CASCADE", name="fk_floating_baselines_robot_id_robots"),
            nullable=False,
        ),
        sa.Column("wall_time", sa.Double(), nullable=False),
        sa.Column("window_end_t", sa.Double(), nullable=True),
        sa.Column("rule", sa.String(length=500), nullable=False),
        sa.Column("data", sa.JSON(), nullable=False),
        sa.PrimaryKeyConstraint("id", name="pk_floating_baselines"),
    )
    op.create_index("ix_floating_baselines_robot_id", "floating_baselines", ["robot_id", "id"])


def downgrade() -> None:
    op.drop_index("ix_floating_baselines_robot_id", table_name="floating_baselines")
    op.drop_table("floating_baselines")
