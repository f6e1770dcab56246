"""Store frame-chunk blobs uncompressed on PostgreSQL (random sensor floats do not compress; trying
costs ingest time). SQLite has no such setting: nothing to do there.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = "0002"
down_revision: str | Sequence[str] | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

BLOBS = ("t", "q", "acc", "gyro")


def _set_storage(mode: str) -> None:
    if op.get_bind().dialect.name != "postgresql":
        return
    for col in BLOBS:
        op.execute(f"ALTER TABLE chunks ALTER COLUMN {col} SET STORAGE {mode}")


def upgrade() -> None:
    _set_storage("EXTERNAL")


def downgrade() -> None:
    _set_storage("EXTENDED")
