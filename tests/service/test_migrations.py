"""Alembic migrations: upgrade an empty database to head, match the models, downgrade to empty."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import inspect

from service.db import Base, current_revision, downgrade, head_revision, make_engine, upgrade

TABLES = {"robots", "joints", "imus", "chunks", "topologies", "baselines", "alerts", "heartbeats"}


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def empty_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'm.db'}"
    make: Callable[[], str] = request.getfixturevalue("new_pg_database")
    return make()


def _tables(engine) -> set[str]:
    return set(inspect(engine).get_table_names()) - {"alembic_version"}


def test_upgrade_from_empty_matches_models_and_downgrades(empty_url: str) -> None:
    engine = make_engine(empty_url)
    try:
        assert current_revision(engine) is None and _tables(engine) == set()
        assert upgrade(engine) == head_revision()
        assert _tables(engine) == TABLES
        with engine.connect() as conn:
            diff = compare_metadata(
                MigrationContext.configure(conn, opts={"compare_type": True}), Base.metadata
            )
        assert diff == [], f"models and migrations differ: {diff}"
        assert upgrade(engine) == head_revision()  # idempotent
        assert downgrade(engine, "base") is None
        assert _tables(engine) == set()
        assert upgrade(engine) == head_revision()
    finally:
        engine.dispose()


def test_alembic_command_line_works_from_any_directory(tmp_path: Path) -> None:
    """Operators run ``alembic -c migrations/alembic.ini``; the URL comes from the settings' environment."""
    import migrations

    ini = Path(migrations.__file__).parent / "alembic.ini"
    db = tmp_path / "cli.db"
    env = {**os.environ, "BODYHEALTH_DATABASE_URL": f"sqlite:///{db}"}
    alembic = [sys.executable, "-m", "alembic", "-c", str(ini)]
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    up = subprocess.run([*alembic, "upgrade", "head"], cwd=elsewhere, env=env, capture_output=True, text=True)
    assert up.returncode == 0, up.stderr
    engine = make_engine(f"sqlite:///{db}")
    try:
        assert current_revision(engine) == head_revision() and _tables(engine) == TABLES
    finally:
        engine.dispose()
    down = subprocess.run(
        [*alembic, "-x", f"url=sqlite:///{db}", "downgrade", "base"],
        cwd=elsewhere,
        env={k: v for k, v in env.items() if k != "BODYHEALTH_DATABASE_URL"},
        capture_output=True,
        text=True,
    )
    assert down.returncode == 0, down.stderr
    engine = make_engine(f"sqlite:///{db}")
    try:
        assert current_revision(engine) is None and _tables(engine) == set()
    finally:
        engine.dispose()


def test_store_creates_schema_only_through_migrations(tmp_path: Path) -> None:
    from service.store import Store

    url = f"sqlite:///{tmp_path / 'deep' / 'nested' / 's.db'}"
    with Store(url) as store:
        assert current_revision(store.engine) == head_revision()
        with store.engine.connect() as conn:
            assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
