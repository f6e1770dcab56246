"""Trained sensor-network weights, kept to start the next training of a robot from (warm start).

Adds ``network_weights``: per robot and method, versioned, with the baseline that was current when
they were trained (service/store/weights.py). Downgrading drops the table: the weights are a cache of
training, every topology learned from them stays.

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-26
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | Sequence[str] | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    op.create_table(
        "network_weights",
        sa.Column("id", BigId, primary_key=True),
        sa.Column(
            "robot_id",
            sa.Integer(),
            sa.ForeignKey("robots.id", ondelete="CASCADE", name="fk_network_weights_robot_id_robots"),
            nullable=False,
        ),
        sa.Column("method", sa.String(64), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("baseline_id", BigId, nullable=True),
        sa.Column("wall_time", sa.Double(), nullable=False),
        sa.Column("window_end_t", sa.Double(), nullable=True),
        sa.Column("imus", sa.JSON(), nullable=False),
        sa.Column("joints", sa.JSON(), nullable=False),
        sa.Column("data", sa.LargeBinary(), nullable=False),
        sa.PrimaryKeyConstraint("id", name="pk_network_weights"),
    )
    op.create_index("ix_network_weights_robot_method", "network_weights", ["robot_id", "method", "version"])
    if op.get_bind().dialect.name == "postgresql":
        op.execute("ALTER TABLE network_weights ALTER COLUMN data SET STORAGE EXTERNAL")


def downgrade() -> None:
    op.drop_index("ix_network_weights_robot_method", table_name="network_weights")
    op.drop_table("network_weights")
