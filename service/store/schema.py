"""Opening the store's database and keeping its schema where the code expects it.

:class:`StoreBase` is the part of :class:`~service.store.Store` every concern shares: the engine, the
session factory, the write lock and the settings the store was opened with. It also owns the schema
step. Opening a store never migrates: changing a production schema is an operator's decision
(``bodyhealth db upgrade``, or ``bodyhealth serve`` at start), and a tool that only reads must not
rewrite a database it was pointed at. Instead the first use of a store checks, once, that the database
is at the revision the shipped migrations call head, and fails with :class:`SchemaMismatch` naming the
command that fixes it rather than with an SQL error about a missing table or column.
:meth:`StoreBase.upgrade` runs the migrations on the store's own engine, which is the only way to migrate
an in-memory SQLite database (another engine would open another, empty, database).

An SQLite store keeps its write-ahead log (WAL) short (:meth:`StoreBase.truncate_wal`). SQLite moves the
WAL into the database file only once it holds 1000 pages (16 MiB here), and then needs room for both
copies at once; on a full disk that checkpoint fails, the WAL cannot be reset, and freeing a little
space only let the WAL take it again. So the frame writes checkpoint and truncate the WAL once it
passes :attr:`StoreBase.wal_truncate_bytes` or half the space left on its file system (a checkpoint may
need as much again in the database file, so it must run while that room is there), and, after a write
failed for lack of space, before every later write until one such checkpoint succeeds: the write that
follows has the room the WAL gave back.

Example
-------
>>> store = StoreBase("sqlite://")          # an empty in-memory database
>>> try:
...     store.check_schema()
... except SchemaMismatch as err:
...     print("bodyhealth db upgrade" in str(err))
True
>>> store.upgrade() == migrate.head_revision() == store.check_schema()
True
>>> store.close()
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Self

from sqlalchemy import ColumnElement, Engine, Select, event, select, text
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from service.db import migrate
from service.db.engine import SQLITE_BUSY_TIMEOUT_MS, make_engine, normalize_url
from service.settings import Settings, get_settings, overridden
from service.store.identity import FileIdentity, sqlite_file
from service.store.write_lock import WriteLock

#: The key of :attr:`Session.info <sqlalchemy.orm.Session.info>` that holds the store's robot ids.
ROBOT_IDS = "robot_ids"
#: A :attr:`Session.info <sqlalchemy.orm.Session.info>` key: the session writes frames (chunks, clocks,
#: parts) and nothing learned from them, so its commits leave ``analysis_generation`` as it is.
FRAMES_ONLY = "frames_only"

__all__ = ["FRAMES_ONLY", "ROBOT_IDS", "SchemaMismatch", "StoreBase", "is_out_of_space", "newest"]

log = logging.getLogger(__name__)

#: SQLite result codes (low byte of an extended code) of a write that found no room: SQLITE_IOERR,
#: SQLITE_FULL.
_NO_ROOM_CODES = (10, 13)


def newest(model: Any, *where: ColumnElement[bool]) -> Select[Any]:
    """The newest row of ``model`` (highest id) meeting ``where``: rows of baselines, geometries and
    alerts are appended, never overwritten, so a robot's current one is its newest."""
    return select(model).where(*where).order_by(model.id.desc()).limit(1)


def is_out_of_space(err: BaseException) -> bool:
    """Whether ``err`` (an SQLAlchemy error or the driver's) is SQLite failing a write for lack of space.

    >>> import sqlite3
    >>> is_out_of_space(sqlite3.OperationalError("database or disk is full"))
    True
    >>> is_out_of_space(sqlite3.OperationalError("database is locked"))
    False
    """
    orig = getattr(err, "orig", None) or err
    code = getattr(orig, "sqlite_errorcode", None)
    if code is not None:
        return code & 0xFF in _NO_ROOM_CODES
    return "disk is full" in str(orig) or "disk I/O error" in str(orig)


class SchemaMismatch(RuntimeError):
    """The database is not at the schema revision this code was written for."""


class StoreBase:
    """Engine, sessions, settings and the schema step of one store (see the module doc).

    ``url`` defaults to the settings' ``database_url``; retention, IMU silence and chunk size come from
    the settings unless given here. ``engine_kwargs`` go to :func:`service.db.engine.make_engine`.
    """

    #: WAL size past which a frame write checkpoints and truncates it (SQLite files): 256 pages of
    #: 16 KiB, a few seconds of a busy fleet's commits, so the WAL and its checkpoint never need more
    #: than a few MiB beside the database.
    wal_truncate_bytes: int = 4 * 2**20
    #: How long a WAL checkpoint waits for readers on an older snapshot before it gives up for now:
    #: the worker's and the API's reads take milliseconds, and the writer waits meanwhile.
    wal_checkpoint_wait_seconds: float = 0.5

    def __init__(
        self,
        url: str | None = None,
        *,
        settings: Settings | None = None,
        retention_seconds: float | None = None,
        imu_silent_seconds: float | None = None,
        chunk_max_samples: int | None = None,
        engine_kwargs: dict[str, Any] | None = None,
    ) -> None:
        s = settings or get_settings()
        self.url = normalize_url(url or s.database_url)
        self.retention_seconds = float(overridden(s, "retention_seconds", retention_seconds))
        self.imu_silent_seconds = float(overridden(s, "imu_silent_seconds", imu_silent_seconds))
        self.chunk_max_samples = int(overridden(s, "chunk_max_samples", chunk_max_samples))
        self.clock_reset_seconds = float(s.clock_reset_seconds)
        self.max_robots = int(s.max_robots)
        self.topology_history_keep = int(s.topology_history_keep)
        self.engine: Engine = make_engine(self.url, **(engine_kwargs or {}))
        # Every robot's id once read, shared by this store's sessions (``Session.info``, see
        # service.store.robots.robot_id): a robot's id never changes and robots are never deleted, and
        # the read routes would otherwise look every robot up in every store call of every rendering.
        self._robot_ids: dict[str, int] = {}
        self._sessions = sessionmaker(self.engine, expire_on_commit=False, info={ROBOT_IDS: self._robot_ids})
        # The SQLite file this store writes to, remembered at the first connection (see
        # service.store.identity): a file deleted or replaced under the service is refused, not written.
        self._file = FileIdentity(sqlite_file(self.url))
        event.listen(self.engine, "connect", lambda *_: self._file.capture())
        # Committed transactions of this store object: readers that keep rendered answers (the API's
        # read cache, service.api.cache) reuse them while it stays the same. ``analysis_generation``
        # leaves out the commits of frames alone (a session marked FRAMES_ONLY): what is learned from
        # the frames (topologies, baselines, alerts) stays the same across them.
        self.generation = 0
        self.analysis_generation = 0
        self._generation_lock = threading.Lock()
        event.listen(self._sessions, "after_commit", self._committed)
        self._write_lock = WriteLock()
        self._schema_checked = False
        # Robots (and their parts) this store has registered, so a stream of frames does not look its
        # robot up batch after batch; see service.store.robots.
        self._known: dict[str, Any] = {}
        # Parsed topology records by (table, id, wall time); see service.store.topologies.
        self._parsed_topologies: dict[tuple[str, int, float], Any] = {}
        # The WAL next to an SQLite file (None otherwise), and whether a write failed for lack of space
        # since the last checkpoint that truncated it (see the module doc).
        db_file = sqlite_file(self.url)
        self._wal: str | None = None if db_file is None else f"{db_file}-wal"
        self._wal_owed = False
        #: Checkpoints that truncated the WAL, and the last one's wall time (monotonic s).
        self.wal_truncations = 0
        self.wal_truncated_at: float | None = None

    def _committed(self, session: Any) -> None:
        with self._generation_lock:
            self.generation += 1
            if not session.info.get(FRAMES_ONLY):
                self.analysis_generation += 1

    # ------------------------------------------------------------------------------- schema
    def upgrade(self) -> str:
        """Migrate the database to the newest revision (Alembic) on this store's engine; returns it."""
        reached = migrate.upgrade(self.engine)
        if reached is None or reached != migrate.head_revision():
            raise SchemaMismatch(f"{self._shown_url()}: migrating stopped at revision {reached}")
        self._schema_checked = True
        return reached

    def check_schema(self) -> str:
        """The database's revision when it is head; raises :class:`SchemaMismatch` otherwise."""
        current = migrate.current_revision(self.engine)
        head = migrate.head_revision()
        if current == head:
            self._schema_checked = True
            return head
        where = self._shown_url()
        if current is None:
            raise SchemaMismatch(
                f"{where} has no bodyhealth schema yet; create it with `bodyhealth db upgrade "
                f"--database-url {where}` (or start `bodyhealth serve`, which upgrades)"
            )
        if current not in migrate.known_revisions():
            raise SchemaMismatch(
                f"{where} is at schema revision {current}, which this bodyhealth does not know "
                f"(its newest is {head}): the database was migrated by a newer version"
            )
        raise SchemaMismatch(
            f"{where} is at schema revision {current}, this bodyhealth needs {head}; run "
            f"`bodyhealth db upgrade --database-url {where}`"
        )

    def _session(self) -> Session:
        """A new ORM session; the first one checks the schema (see the module doc). Raises
        :class:`~service.store.identity.DatabaseFileChanged` once the SQLite file is not the one opened."""
        self._file.ensure()
        if not self._schema_checked:
            self.check_schema()
        return self._sessions()

    @contextmanager
    def _writing(self) -> Iterator[Session]:
        """A session in a write transaction, taken after this store's write lock.

        Writers of one process queue on the lock, and the next wakes the moment the last commits.
        Without it they meet in SQLite's own lock, whose busy handler sleeps in steps of up to 100 ms
        before it tries again: under ingest load an operator's approval waited there for hundreds of
        milliseconds behind frame commits that took tens. A long wait is logged with the writer it
        waited behind (:mod:`service.store.write_lock`); so is a long hold, with its commit's share
        and the WAL's size when the commit began (the lock logs both)."""
        with self._write_lock as lock, self._session() as s:
            with s.begin():
                yield s
                wal, t0 = self.wal_bytes(), time.monotonic()
            lock.committed(time.monotonic() - t0, wal)

    # ----------------------------------------------------------------------------- plumbing
    @property
    def write_lock(self) -> WriteLock:
        """The lock this store's writers queue on; its counts of slow waits go to ``/metrics``."""
        return self._write_lock

    @property
    def dialect(self) -> str:
        return self.engine.dialect.name

    def _insert(self, table: Any) -> Any:
        """An INSERT that understands ON CONFLICT on both backends."""
        return (postgresql.insert if self.dialect == "postgresql" else sqlite.insert)(table)

    def _shown_url(self) -> str:
        return self.engine.url.render_as_string(hide_password=True)

    def storage_fault(self) -> str | None:
        """Why the store must not be written to (its SQLite file was deleted or replaced), or None.
        Cheap (one ``stat``): the readiness probe and the ingest writer's prune ask it."""
        return self._file.check()

    def ping(self) -> bool:
        """True when the database answers (whatever its schema) and is still the file first opened; a
        deleted file is not reopened here, which would create an empty one in its place."""
        if self._file.check() is not None:
            return False
        try:
            with self.engine.connect() as conn:
                return conn.execute(text("SELECT 1")).scalar() == 1
        except SQLAlchemyError:
            return False

    # ------------------------------------------------------------------------------- the WAL
    def wal_bytes(self) -> int:
        """Size of the SQLite WAL file now (0 without one: PostgreSQL, in memory, not yet written)."""
        if self._wal is None:
            return 0
        try:
            return os.stat(self._wal).st_size
        except OSError:
            return 0

    def truncate_wal(self) -> bool:
        """Move the WAL into the database file and truncate it to zero bytes (``PRAGMA
        wal_checkpoint(TRUNCATE)``); True when it was done. False, leaving everything as it was, when
        readers held an older snapshot for :attr:`wal_checkpoint_wait_seconds` or the database file
        had no room to take the WAL's pages (a full disk). Nothing to do (True) without an SQLite file.

        The copying is done first by a passive checkpoint, outside the write lock: it writes the
        WAL's pages into the database file and syncs it while other writers go on (SQLite lets one
        checkpoint run beside the writer). Under the lock the truncating checkpoint then has only the
        frames committed meanwhile to copy. Done under the lock, the whole copy and its sync held every
        other writer, an operator's approval among them, for 100-500 ms on a loaded machine
        (docs/alert-latency.md).
        """
        if self._wal is None:
            return True
        self._checkpoint("PASSIVE")
        with self._write_lock:
            busy = self._checkpoint("TRUNCATE")
            if busy is None or busy:
                return False
            self._wal_owed = False
            self.wal_truncations += 1
            self.wal_truncated_at = time.monotonic()
            return True

    def _checkpoint(self, mode: str) -> int | None:
        """``PRAGMA wal_checkpoint(mode)``'s first column (1: it could not finish for readers or a
        writer), waiting at most :attr:`wal_checkpoint_wait_seconds` for them; None when it failed."""
        try:
            with self.engine.connect() as conn:
                wait_ms = int(1000 * self.wal_checkpoint_wait_seconds)
                conn.exec_driver_sql(f"PRAGMA busy_timeout={wait_ms}")
                try:
                    return int(conn.exec_driver_sql(f"PRAGMA wal_checkpoint({mode})").scalar() or 0)
                finally:
                    conn.exec_driver_sql(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        except SQLAlchemyError as err:
            log.info("WAL checkpoint (%s) failed: %s", mode.lower(), getattr(err, "orig", err))
            return None

    def _before_write(self) -> None:
        """Before a frame write: after a failure for lack of space, first give the WAL's room back."""
        if self._wal_owed and self.truncate_wal():
            log.info("WAL truncated after a write failed for lack of space; writing again")

    def wal_free_bytes(self) -> float:
        """Bytes free to this process on the WAL's file system (infinite when it cannot be told)."""
        if self._wal is None:
            return float("inf")
        try:
            st = os.statvfs(os.path.dirname(self._wal))
        except OSError:
            return float("inf")
        return float(st.f_bavail * st.f_frsize)

    def _after_write(self, err: BaseException | None) -> None:
        """After a frame write (``err``: why it failed): owe a truncation after a lack of space, and
        truncate a WAL that passed :attr:`wal_truncate_bytes` or half the free space."""
        if self._wal is None:
            return
        if err is not None:
            self._wal_owed = self._wal_owed or is_out_of_space(err)
            return
        wal = self.wal_bytes()
        if wal > self.wal_truncate_bytes or wal > self.wal_free_bytes() / 2:
            self.truncate_wal()

    def close(self) -> None:
        """Release every pooled connection."""
        self.engine.dispose()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Store({self._shown_url()!r})"
