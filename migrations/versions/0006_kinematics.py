"""A robot's geometry baseline: joint axes and IMU lever arms, what drift alerts compare against.

Adds ``kinematics``: per robot, the kinematics JSON learned while a topology baseline was current
(service/store/kinematics.py). Downgrading drops the table: the geometry is learned again from the
next windows.

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-26
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | Sequence[str] | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    op.create_table(
        "kinematics",
        sa.Column("id", BigId, primary_key=True),
        sa.Column(
            "robot_id",
            sa.Integer(),
            sa.ForeignKey("robots.id", ondelete="CASCADE", name="fk_kinematics_robot_id_robots"),
            nullable=False,
        ),
        sa.Column("baseline_id", BigId, nullable=False),
        sa.Column("wall_time", sa.Double(), nullable=False),
        sa.Column("window_end_t", sa.Double(), nullable=True),
        sa.Column("data", sa.JSON(), nullable=False),
        sa.PrimaryKeyConstraint("id", name="pk_kinematics"),
    )
    op.create_index("ix_kinematics_robot_baseline", "kinematics", ["robot_id", "baseline_id"])


def downgrade() -> None:
    op.drop_index("ix_kinematics_robot_baseline", table_name="kinematics")
    op.drop_table("kinematics")
