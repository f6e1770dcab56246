"""Initial schema: robots, joints, IMUs, frame chunks, topologies, baselines, alerts, heartbeats.

Revision ID: 0001
Revises:
Create Date: 2026-11-22
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | Sequence[str] | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BigId = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def _robot_fk(table: str) -> sa.ForeignKeyConstraint:
    return sa.ForeignKeyConstraint(
        ["robot_id"], ["robots.id"], name=op.f(f"fk_{table}_robot_id_robots"), ondelete="CASCADE"
    )


def upgrade() -> None:
    op.create_table(
        "heartbeats",
        sa.Column("component", sa.String(length=200), nullable=False),
        sa.Column("wall_time", sa.Double(), nullable=False),
        sa.PrimaryKeyConstraint("component", name=op.f("pk_heartbeats")),
    )
    op.create_table(
        "robots",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("first_seen", sa.Double(), nullable=False),
        sa.Column("last_frame_t", sa.Double(), nullable=True),
        sa.Column("simulated", sa.Boolean(), nullable=False),
        sa.Column("catalog", sa.String(length=200), nullable=True),
        sa.Column("excitation", sa.JSON(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_robots")),
        sa.UniqueConstraint("name", name=op.f("uq_robots_name")),
    )
    op.create_table(
        "joints",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("position", sa.Integer(), nullable=False),
        _robot_fk("joints"),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_joints")),
        sa.UniqueConstraint("robot_id", "name", name=op.f("uq_joints_robot_id_name")),
    )
    op.create_table(
        "imus",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("position", sa.Integer(), nullable=False),
        sa.Column("first_t", sa.Double(), nullable=False),
        sa.Column("last_t", sa.Double(), nullable=False),
        _robot_fk("imus"),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_imus")),
        sa.UniqueConstraint("robot_id", "name", name=op.f("uq_imus_robot_id_name")),
    )
    op.create_table(
        "chunks",
        sa.Column("id", BigId, nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("t_start", sa.Double(), nullable=False),
        sa.Column("t_end", sa.Double(), nullable=False),
        sa.Column("n", sa.Integer(), nullable=False),
        sa.Column("joint_names", sa.JSON(), nullable=False),
        sa.Column("imu_names", sa.JSON(), nullable=False),
        sa.Column("t", sa.LargeBinary(), nullable=False),
        sa.Column("q", sa.LargeBinary(), nullable=False),
        sa.Column("acc", sa.LargeBinary(), nullable=False),
        sa.Column("gyro", sa.LargeBinary(), nullable=False),
        _robot_fk("chunks"),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_chunks")),
    )
    op.create_index("ix_chunks_robot_time", "chunks", ["robot_id", "t_start", "t_end"])
    op.create_table(
        "topologies",
        sa.Column("id", BigId, nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("wall_time", sa.Double(), nullable=False),
        sa.Column("window_end_t", sa.Double(), nullable=True),
        sa.Column("method", sa.String(length=64), nullable=False),
        sa.Column("topology", sa.JSON(), nullable=False),
        _robot_fk("topologies"),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_topologies")),
    )
    op.create_index("ix_topologies_robot_wall", "topologies", ["robot_id", "wall_time"])
    op.create_table(
        "baselines",
        sa.Column("id", BigId, nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("wall_time", sa.Double(), nullable=False),
        sa.Column("window_end_t", sa.Double(), nullable=True),
        sa.Column("method", sa.String(length=64), nullable=False),
        sa.Column("source", sa.String(length=16), nullable=False),
        sa.Column("topology", sa.JSON(), nullable=False),
        _robot_fk("baselines"),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_baselines")),
    )
    op.create_index("ix_baselines_robot_id", "baselines", ["robot_id", "id"])
    op.create_table(
        "alerts",
        sa.Column("id", BigId, nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=64), nullable=False),
        sa.Column("part", sa.String(length=210), nullable=False),
        sa.Column("imu", sa.String(length=200), nullable=True),
        sa.Column("joint", sa.String(length=200), nullable=True),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("acked", sa.Boolean(), nullable=False),
        sa.Column("raised_at", sa.Double(), nullable=False),
        sa.Column("resolved_at", sa.Double(), nullable=True),
        sa.Column("updated_at", sa.Double(), nullable=False),
        sa.Column("finding", sa.JSON(), nullable=False),
        _robot_fk("alerts"),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_alerts")),
    )
    op.create_index("ix_alerts_robot_kind_part", "alerts", ["robot_id", "kind", "part"])
    op.create_index(op.f("ix_alerts_state"), "alerts", ["state"])


def downgrade() -> None:
    op.drop_index(op.f("ix_alerts_state"), table_name="alerts")
    op.drop_index("ix_alerts_robot_kind_part", table_name="alerts")
    op.drop_table("alerts")
    op.drop_index("ix_baselines_robot_id", table_name="baselines")
    op.drop_table("baselines")
    op.drop_index("ix_topologies_robot_wall", table_name="topologies")
    op.drop_table("topologies")
    op.drop_index("ix_chunks_robot_time", table_name="chunks")
    op.drop_table("chunks")
    op.drop_table("imus")
    op.drop_table("joints")
    op.drop_table("robots")
    op.drop_table("heartbeats")
