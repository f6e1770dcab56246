"""Which file an SQLite store is writing to, and whether it is still the one at the configured path.

An SQLite connection holds its database file open. When the file is deleted (an over-eager clean-up,
a volume re-mounted) or replaced (a backup restored by copying over it), the open connections keep
reading and writing the old inode: every commit succeeds, and every commit is lost at the next
restart. Nothing in SQLite reports this, so the store remembers the file's identity (``st_dev``,
``st_ino``) the first time it connects and compares it with what the path names now. A mismatch is a
:class:`DatabaseFileChanged`, raised before any further session is opened, so nothing more goes to
the orphaned inode; the operator sees it on ``/readyz`` and in one ERROR log line.

PostgreSQL and in-memory SQLite have no file to watch: :meth:`FileIdentity.check` is then always None.

Example
-------
>>> import os, tempfile
>>> path = os.path.join(tempfile.mkdtemp(), "x.db")
>>> ident = FileIdentity(path)
>>> open(path, "w").close(); ident.capture(); ident.check() is None
True
>>> os.remove(path); ident.check().endswith("was deleted")
True
>>> open(path, "w").close(); ident.check().endswith("was deleted")  # kept: a new file is not the old one
True
"""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

from sqlalchemy.exc import SQLAlchemyError

__all__ = ["DatabaseFileChanged", "FileIdentity", "sqlite_file"]

log = logging.getLogger(__name__)


class DatabaseFileChanged(SQLAlchemyError):
    """The SQLite file the store opened was deleted or replaced under it.

    A :class:`~sqlalchemy.exc.SQLAlchemyError`, so every caller that already copes with an unavailable
    database (the ingest writer's retries, the API's 503) copes with this one the same way."""


def sqlite_file(url: str) -> Path | None:
    """The absolute path of an SQLite file URL; None for PostgreSQL and in-memory databases.

    >>> sqlite_file("sqlite:///:memory:") is None, sqlite_file("postgresql+psycopg://h/db") is None
    (True, True)
    >>> sqlite_file("sqlite:////var/x.db")
    PosixPath('/var/x.db')
    """
    from sqlalchemy.engine import make_url

    u = make_url(url)
    if u.get_backend_name() != "sqlite":
        return None
    db = u.database or ""
    if db in ("", ":memory:") or db.startswith("file:"):
        return None
    return Path(db).expanduser().resolve()


class FileIdentity:
    """The ``(st_dev, st_ino)`` of one database file, captured once and checked on demand.

    ``path`` None (no file) makes every check pass. The first fault found is logged at ERROR once and
    then kept: a file that was replaced does not become the right one again by being replaced back.
    """

    def __init__(self, path: Path | str | None) -> None:
        self.path = None if path is None else Path(path)
        self._ident: tuple[int, int] | None = None
        self._fault: str | None = None
        self._lock = threading.Lock()

    def capture(self) -> None:
        """Remember the identity of the file now at the path (first call only; the connection that
        created or opened the file calls this)."""
        if self.path is None or self._ident is not None:
            return
        try:
            st = os.stat(self.path)
        except OSError:
            return
        with self._lock:
            if self._ident is None:
                self._ident = (st.st_dev, st.st_ino)

    def check(self) -> str | None:
        """None while the path still names the file first opened; otherwise why not (and from then on)."""
        if self._fault is not None or self.path is None or self._ident is None:
            return self._fault
        fault = self._compare()
        if fault is not None:
            with self._lock:
                first = self._fault is None
                self._fault = self._fault or fault
            if first:
                log.error("storage fault: %s; writes are refused until the service is restarted", fault)
        return self._fault

    def _compare(self) -> str | None:
        try:
            st = os.stat(self.path)  # type: ignore[arg-type]
        except FileNotFoundError:
            return f"database file {self.path} was deleted"
        except OSError as err:
            return f"database file {self.path} cannot be examined: {err.strerror}"
        if (st.st_dev, st.st_ino) != self._ident:
            return f"database file {self.path} was replaced (inode {self._ident[1]} -> {st.st_ino})"  # type: ignore[index]
        return None

    def ensure(self) -> None:
        """Raise :class:`DatabaseFileChanged` when :meth:`check` finds a fault."""
        fault = self.check()
        if fault is not None:
            raise DatabaseFileChanged(fault)
