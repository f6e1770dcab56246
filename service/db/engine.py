"""Engines and sessions for the store: SQLite (WAL) or PostgreSQL, chosen by URL.

SQLite runs in WAL mode with ``synchronous=NORMAL``: a committed transaction survives the process being
killed (the WAL lives in the OS page cache), readers never block the writer, and a busy writer makes
others wait (``busy_timeout``) instead of failing. PostgreSQL URLs without a driver get psycopg 3.

Example
-------
>>> eng = make_engine("sqlite://")
>>> with eng.connect() as conn:
...     conn.exec_driver_sql("PRAGMA foreign_keys").scalar()
1
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import StaticPool

__all__ = ["SQLITE_JOURNAL_SIZE_LIMIT", "is_sqlite", "make_engine", "normalize_url", "session_scope"]

#: How long (ms) an SQLite connection waits for another writer before giving up.
SQLITE_BUSY_TIMEOUT_MS = 30_000
#: Page size of new SQLite files, bytes.
SQLITE_PAGE_SIZE = 16384
#: Page cache per SQLite connection, KiB.
SQLITE_CACHE_KIB = 65536
#: Bytes an SQLite WAL file is truncated back to after a checkpoint. Without a limit the file keeps the
#: size of its largest burst (a backlog of frame chunks written at once) for the life of the database.
SQLITE_JOURNAL_SIZE_LIMIT = 64 * 1024 * 1024


def normalize_url(url: str) -> str:
    """``postgresql://`` and ``postgres://`` become ``postgresql+psycopg://`` (the driver we ship)."""
    if url.startswith("postgres://"):
        url = "postgresql://" + url[len("postgres://") :]
    if url.startswith("postgresql://"):
        url = "postgresql+psycopg://" + url[len("postgresql://") :]
    return url


def is_sqlite(url: str) -> bool:
    return make_url(normalize_url(url)).get_backend_name() == "sqlite"


def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
    cur = dbapi_conn.cursor()
    try:
        # Page size trades bulk speed against bytes written per commit. Every commit rewrites each page it
        # touches in the WAL (the chunk rows' pages, their index, the robot's and the IMUs' rows): with
        # 64 KiB pages a streaming robot's commits wrote several times the frames' own bytes; 16 KiB
        # pages stay within the 2x target at the default commit interval while bulk writes keep most of
        # the speed of big pages (docs/bench/writes.md, docs/bench/store.md). It only takes effect on a
        # new database file, so it must come before WAL mode creates one.
        cur.execute(f"PRAGMA page_size={SQLITE_PAGE_SIZE}")
        cur.execute(f"PRAGMA cache_size=-{SQLITE_CACHE_KIB}")
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute(f"PRAGMA journal_size_limit={SQLITE_JOURNAL_SIZE_LIMIT}")
        cur.execute("PRAGMA synchronous=NORMAL")
        cur.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        cur.execute("PRAGMA foreign_keys=ON")
    finally:
        cur.close()


def make_engine(url: str, **kwargs: Any) -> Engine:
    """An engine for ``url``; creates the parent folder of an SQLite file."""
    url = normalize_url(url)
    u = make_url(url)
    if u.get_backend_name() == "sqlite":
        db = u.database or ""
        memory = db in ("", ":memory:") or db.startswith("file::memory:")
        if memory:
            # One shared connection: a per-thread pool would give each thread its own empty database.
            kwargs.setdefault("poolclass", StaticPool)
        else:
            Path(db).expanduser().resolve().parent.mkdir(parents=True, exist_ok=True)
        kwargs.setdefault(
            "connect_args", {"check_same_thread": False, "timeout": SQLITE_BUSY_TIMEOUT_MS / 1000}
        )
        engine = create_engine(url, **kwargs)
        event.listen(engine, "connect", _sqlite_pragmas)
        return engine
    kwargs.setdefault("pool_pre_ping", True)
    return create_engine(url, **kwargs)


@contextmanager
def session_scope(engine_or_factory: Engine | sessionmaker[Session]) -> Iterator[Session]:
    """A session in one transaction: committed on success, rolled back on error, always closed."""
    factory = (
        engine_or_factory
        if isinstance(engine_or_factory, sessionmaker)
        else sessionmaker(engine_or_factory, expire_on_commit=False)
    )
    with factory() as session, session.begin():
        yield session
