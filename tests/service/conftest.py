"""Database fixtures for the service tests: real SQLite and real PostgreSQL, never mocks.

* ``db_url`` — parametrized: an SQLite file in the test's tmp dir, and a PostgreSQL database (marked
  ``postgres``). The PostgreSQL database is created once per test session (``bodyhealth_test_<random>``),
  emptied after every test that used it, and dropped at the end.
* ``store`` — a :class:`service.store.Store` on ``db_url`` (upgraded to head), closed afterwards.
* ``postgres_server`` — an admin URL of a PostgreSQL server: the one on 127.0.0.1:5432 when it answers
  (or ``BODYHEALTH_TEST_POSTGRES_URL``), else a throwaway cluster started from Debian's binaries in a
  temp dir on a free port; skips, saying why, when neither works.
* ``new_pg_database`` — a factory for extra empty PostgreSQL databases (migration tests).
* ``pg_cluster`` — a PostgreSQL server of the test's own (:class:`tests.service.faults.PgCluster`), to
  stop and start under a running service; never the shared one.
* ``small_disk`` — room for an SQLite store that can run out and be given back
  (:class:`tests.service.faults.SmallDisk`).
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
import tempfile
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from tests.ports import free_port

if TYPE_CHECKING:
    from tests.service.faults import PgCluster, SmallDisk

ADMIN_ENV = "BODYHEALTH_TEST_POSTGRES_URL"
DEFAULT_ADMIN = "postgresql://postgres@127.0.0.1:5432/postgres"


def _answers(conninfo: str) -> bool:
    import psycopg

    try:
        with psycopg.connect(conninfo, connect_timeout=3) as conn:
            conn.execute("SELECT 1")
        return True
    except psycopg.Error:
        return False


def _start_cluster() -> tuple[str, Callable[[], None]] | str:
    """Start a throwaway cluster; returns (admin URL, stop) or the reason it could not."""
    initdbs = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    if not initdbs:
        return "no PostgreSQL server answers on 127.0.0.1:5432 and no initdb under /usr/lib/postgresql"
    bindir = Path(initdbs[-1]).parent
    # Not under pytest's tmp dir: that is private to the user running the tests, and as root the
    # cluster must run as the postgres user, who needs to reach its data folder.
    base = Path(tempfile.mkdtemp(prefix="bodyhealth-pg-"))
    data, port = base / "pgdata", free_port()
    prefix: list[str] = []
    if os.geteuid() == 0:  # initdb refuses to run as root
        runuser = shutil.which("runuser")
        if runuser is None:
            return "running as root without runuser; cannot start a PostgreSQL cluster"
        try:
            pw = pwd.getpwnam("postgres")
        except KeyError:
            return "running as root and there is no postgres user to run a PostgreSQL cluster"
        os.chown(base, pw.pw_uid, pw.pw_gid)
        prefix = [runuser, "-u", "postgres", "--"]
    pg_ctl = [*prefix, str(bindir / "pg_ctl"), "-D", str(data)]
    try:
        subprocess.run(
            [
                *prefix,
                str(bindir / "initdb"),
                "-D",
                str(data),
                "-U",
                "postgres",
                "--auth=trust",
                "-E",
                "UTF8",
            ],
            check=True,
            capture_output=True,
            timeout=120,
        )
        subprocess.run(
            [
                *pg_ctl,
                "-l",
                str(base / "pg.log"),
                "-w",
                "-o",
                f"-p {port} -k {base} -c listen_addresses=127.0.0.1 -c fsync=off",
                "start",
            ],
            check=True,
            capture_output=True,
            timeout=120,
        )
    except subprocess.CalledProcessError as err:
        shutil.rmtree(base, ignore_errors=True)
        why = (err.stderr or b"").decode(errors="replace").strip().splitlines()[-1:] or [str(err)]
        return f"could not start a throwaway PostgreSQL cluster: {why[0]}"
    except (subprocess.SubprocessError, OSError) as err:
        shutil.rmtree(base, ignore_errors=True)
        return f"could not start a throwaway PostgreSQL cluster: {err}"

    def stop() -> None:
        subprocess.run([*pg_ctl, "-m", "immediate", "stop"], capture_output=True, timeout=60)
        shutil.rmtree(base, ignore_errors=True)

    return f"postgresql://postgres@127.0.0.1:{port}/postgres", stop


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """Admin conninfo (libpq URL, database ``postgres``) of a reachable PostgreSQL server."""
    url = os.environ.get(ADMIN_ENV, DEFAULT_ADMIN)
    if _answers(url):
        yield url
        return
    started = _start_cluster()
    if isinstance(started, str):
        pytest.skip(started)
    url, stop = started
    try:
        yield url
    finally:
        stop()


def _with_db(admin: str, name: str) -> str:
    return admin.rsplit("/", 1)[0] + "/" + name


def _create_db(admin: str) -> str:
    import psycopg

    name = f"bodyhealth_test_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    return name


def _drop_db(admin: str, name: str) -> None:
    import psycopg

    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def _sqlalchemy_url(conninfo: str) -> str:
    return conninfo.replace("postgresql://", "postgresql+psycopg://", 1)


@pytest.fixture(scope="session")
def pg_database(postgres_server: str) -> Iterator[str]:
    """SQLAlchemy URL of a database created for this test session (dropped at the end)."""
    name = _create_db(postgres_server)
    try:
        yield _sqlalchemy_url(_with_db(postgres_server, name))
    finally:
        _drop_db(postgres_server, name)


@pytest.fixture
def new_pg_database(postgres_server: str) -> Iterator[Callable[[], str]]:
    """Factory of fresh, empty PostgreSQL databases (SQLAlchemy URLs), all dropped after the test."""
    made: list[str] = []

    def make() -> str:
        made.append(_create_db(postgres_server))
        return _sqlalchemy_url(_with_db(postgres_server, made[-1]))

    yield make
    for name in made:
        _drop_db(postgres_server, name)


def _empty_pg(url: str) -> None:
    """Delete every row (schema and Alembic version stay) so the next test starts clean."""
    import psycopg

    conninfo = url.replace("postgresql+psycopg://", "postgresql://", 1)
    with psycopg.connect(conninfo, autocommit=True) as conn:
        tables = [
            r[0]
            for r in conn.execute(
                "SELECT tablename FROM pg_tables"
                " WHERE schemaname = 'public' AND tablename <> 'alembic_version'"
            )
        ]
        if tables:
            conn.execute("TRUNCATE " + ", ".join(f'"{t}"' for t in tables) + " RESTART IDENTITY CASCADE")


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def db_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """A database URL, once for SQLite and once for PostgreSQL (emptied after each test)."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'store.db'}"
        return
    url = request.getfixturevalue("pg_database")
    try:
        yield url
    finally:
        _empty_pg(url)


@pytest.fixture
def store(db_url: str) -> Iterator[object]:
    """A :class:`service.store.Store` on ``db_url``, upgraded to the newest schema."""
    from service.store import open_store

    s = open_store(db_url)
    try:
        yield s
    finally:
        s.close()


@pytest.fixture
def pg_cluster() -> Iterator[PgCluster]:
    from tests.service.faults import PgCluster

    cluster = PgCluster()
    try:
        yield cluster
    finally:
        cluster.destroy()


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[SmallDisk]:
    from tests.service.faults import SmallDisk

    disk = SmallDisk(tmp_path)
    try:
        yield disk
    finally:
        disk.close()
