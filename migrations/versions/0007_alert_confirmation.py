"""Alerts say whether the sensor networks confirmed them; robots say what the worker waits on.

Adds ``alerts.confirmed`` (None: not the networks' to judge, or not judged yet; False: the fast
screen's finding stands, the networks did not answer in time), ``alerts.note`` (why the alert is in
its state: waiting for confirmation, withdrawn and why) and ``robots.waiting`` (what the worker waits
on for the robot, since when, and its retrains' place in the training queue). Downgrading drops them:
the worker writes them again in its next cycles.

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-28
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | Sequence[str] | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("alerts", sa.Column("confirmed", sa.Boolean(), nullable=True))
    op.add_column("alerts", sa.Column("note", sa.String(length=500), nullable=True))
    op.add_column("robots", sa.Column("waiting", sa.JSON(), nullable=True))


def downgrade() -> None:
    # a plain DROP COLUMN (SQLite 3.35+): a batch copy would drop and re-create ``robots``, and its
    # ON DELETE CASCADE would take every robot's frames with it
    op.drop_column("robots", "waiting")
    op.drop_column("alerts", "note")
    op.drop_column("alerts", "confirmed")
