"""Alembic migrations: upgrade an empty database to head, match the models, downgrade to empty; the
store never migrates by itself, and ``bodyhealth db`` takes the step by hand."""

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

REPO = Path(__file__).resolve().parents[2]
TABLES = {
    "robots",
    "joints",
    "imus",
    "chunks",
    "topologies",
    "baselines",
    "alerts",
    "heartbeats",
    "network_weights",
    "kinematics",
    "floating_baselines",
}


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
    from service.store import open_store

    url = f"sqlite:///{tmp_path / 'deep' / 'nested' / 's.db'}"
    with open_store(url) as store:
        assert current_revision(store.engine) == head_revision()
        with store.engine.connect() as conn:
            assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"


def test_upgrade_keeps_single_clock_chunks_of_an_old_database(empty_url: str) -> None:
    """A database at 0002 with frames in it upgrades to head; its chunks read back exactly, multi-rate
    chunks can then be added, and a downgrade to 0002 drops only those (the old schema has one clock)."""
    import math

    import numpy as np
    from sqlalchemy import text

    from service.frames import FrameBatch
    from service.store import Store

    rng = np.random.default_rng(3)
    t = np.arange(20) / 100.0
    q, acc, gyro = rng.normal(size=(20, 2)), rng.normal(size=(20, 1, 3)), rng.normal(size=(20, 1, 3))
    engine = make_engine(empty_url)
    try:
        assert upgrade(engine, "0002") == "0002"
        with engine.begin() as conn:
            conn.execute(
                text(
                    "INSERT INTO robots (id, name, first_seen, last_frame_t, simulated, excitation) "
                    "VALUES (1, 'old', 0.0, 0.19, false, '{}')"
                )
            )
            conn.execute(
                text(
                    "INSERT INTO chunks (robot_id, t_start, t_end, n, joint_names, imu_names, "
                    "t, q, acc, gyro) VALUES (1, 0.0, 0.19, 20, :jn, :kn, :t, :q, :acc, :gyro)"
                ),
                {
                    "jn": '["j1", "j2"]',
                    "kn": '["imu0"]',
                    "t": t.tobytes(),
                    "q": q.tobytes(),
                    "acc": acc.tobytes(),
                    "gyro": gyro.tobytes(),
                },
            )
        assert upgrade(engine) == head_revision()
        with Store(empty_url) as store:
            rec = store.read_between("old", -math.inf, math.inf)
            assert not rec.is_multirate and rec.joint_names == ("j1", "j2")
            for name, want in (("t", t), ("q", q), ("acc", acc), ("gyro", gyro)):
                np.testing.assert_array_equal(getattr(rec, name), want)
            tq = 0.2 + np.arange(25) * 0.004
            store.write(
                FrameBatch(
                    "old",
                    0.2 + np.arange(10) * 0.01,
                    ("j1", "j2"),
                    np.zeros((25, 2)),
                    ("imu0",),
                    np.ones((10, 1, 3)),
                    np.ones((10, 1, 3)),
                    t_q=tq,
                )
            )
            rec = store.read_between("old", -math.inf, math.inf)
            assert rec.is_multirate and rec.n_samples == 30
            np.testing.assert_array_equal(rec.t_q, np.concatenate([t, tq]))
        assert downgrade(engine, "0002") == "0002"
        with engine.connect() as conn:
            assert conn.execute(text("SELECT n FROM chunks")).scalars().all() == [20]
    finally:
        engine.dispose()


def test_store_used_before_upgrade_names_the_command(empty_url: str) -> None:
    """Opening does not migrate; the first use says what to run instead of failing on a missing table."""
    from service.store import SchemaMismatch, Store

    with Store(empty_url) as store:
        with pytest.raises(SchemaMismatch, match="bodyhealth db upgrade"):
            store.robots()
        with pytest.raises(SchemaMismatch, match="no bodyhealth schema"):
            store.write(_batch())
        assert store.ping()  # a reachable database answers whatever its schema
        assert _tables(store.engine) == set()  # nothing was created behind the caller's back
        assert store.upgrade() == head_revision()
        assert store.write(_batch()) == 3 and [r.name for r in store.robots()] == ["arm"]
    with Store(empty_url) as again:  # at head: a plain open is all it takes
        assert again.sample_count("arm") == 3


def test_store_on_an_older_revision_names_both_revisions(tmp_path: Path) -> None:
    from service.store import SchemaMismatch, Store

    url = f"sqlite:///{tmp_path / 'old.db'}"
    engine = make_engine(url)
    try:
        upgrade(engine, "0002")
    finally:
        engine.dispose()
    with Store(url) as store:
        with pytest.raises(SchemaMismatch, match=f"revision 0002, this bodyhealth needs {head_revision()}"):
            store.sample_count()
        store.upgrade()
        assert store.sample_count() == 0


def test_in_memory_store_upgrades_on_its_own_engine() -> None:
    from service.store import Store

    with Store("sqlite://") as store:
        assert store.upgrade() == head_revision() == current_revision(store.engine)
        assert store.write(_batch()) == 3


def _bodyhealth(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-m", "cli", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=120
    )


def test_bodyhealth_db_upgrade_and_current(tmp_path: Path) -> None:
    """``bodyhealth db current`` reports an empty database, ``db upgrade`` brings it to head."""
    from service.store import Store

    db = tmp_path / "var" / "cli.db"
    url = f"sqlite:///{db}"
    cur = _bodyhealth("db", "current", "--database-url", url, cwd=tmp_path)
    assert cur.returncode == 0, cur.stderr
    assert cur.stdout.splitlines() == ["current: none", f"head: {head_revision()}"]
    assert not db.exists()  # looking did not create it

    up = _bodyhealth("db", "upgrade", "--database-url", url, cwd=tmp_path)
    assert up.returncode == 0, up.stderr
    assert f"at revision {head_revision()} (head)" in up.stdout
    engine = make_engine(url)
    try:
        assert current_revision(engine) == head_revision() and _tables(engine) == TABLES
    finally:
        engine.dispose()
    cur = _bodyhealth("db", "current", "--database-url", url, cwd=tmp_path)
    assert cur.returncode == 0, cur.stderr
    assert cur.stdout.splitlines() == [f"current: {head_revision()}", f"head: {head_revision()}"]
    with Store(url) as store:
        assert store.robots() == []

    again = _bodyhealth("db", "upgrade", "--database-url", url, cwd=tmp_path)  # idempotent
    assert again.returncode == 0, again.stderr
    bare = _bodyhealth("db", cwd=tmp_path)
    assert bare.returncode == 2 and "upgrade" in bare.stderr


def _batch() -> object:
    import numpy as np

    from service.frames import FrameBatch

    ones = np.ones((3, 1, 3))
    return FrameBatch("arm", np.arange(3) * 0.01, ("j1",), np.zeros((3, 1)), ("imu0",), ones, ones)
