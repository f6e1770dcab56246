"""Run the Alembic migrations from code: the only way the store's schema is created or changed.

:func:`upgrade` is what :meth:`service.store.Store.upgrade` runs (and with it ``bodyhealth db upgrade``
and ``bodyhealth serve`` at start); opening a store only compares :func:`current_revision` with
:func:`head_revision`. The migration scripts are found through the installed ``migrations`` package, so
this works from any working directory.

Example
-------
>>> from service.db.engine import make_engine
>>> eng = make_engine("sqlite://")
>>> upgrade(eng) == head_revision()
True
>>> downgrade(eng, "base") is None
True
"""

from __future__ import annotations

import functools
import logging
import time
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine
from sqlalchemy.exc import DBAPIError

__all__ = ["alembic_config", "current_revision", "downgrade", "head_revision", "known_revisions", "upgrade"]

log = logging.getLogger(__name__)


def _migrations_dir() -> Path:
    import migrations

    return Path(migrations.__file__).resolve().parent


def alembic_config(url: str | None = None) -> Config:
    """An Alembic :class:`Config` pointing at the shipped ``migrations/`` (ini file included)."""
    ini = _migrations_dir() / "alembic.ini"
    cfg = Config(str(ini))
    cfg.set_main_option("script_location", str(_migrations_dir()))
    cfg.attributes["configure_logger"] = False
    if url is not None:
        cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


@functools.cache
def _scripts() -> ScriptDirectory:
    # Read once per process: every store checks its schema against it, and the scripts do not change
    # while the code that ships them runs.
    return ScriptDirectory.from_config(alembic_config())


def head_revision() -> str:
    """The newest revision the shipped scripts know."""
    head = _scripts().get_current_head()
    assert head is not None
    return head


def known_revisions() -> frozenset[str]:
    """Every revision the shipped scripts know (a database at another one was migrated by newer code)."""
    return frozenset(rev.revision for rev in _scripts().walk_revisions())


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at (None for an empty database)."""
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def _run(engine: Engine, fn: object, revision: str) -> None:
    cfg = alembic_config()
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        fn(cfg, revision)  # type: ignore[operator]


def upgrade(engine: Engine, revision: str = "head", retries: int = 3) -> str | None:
    """Migrate to ``revision`` and return the revision reached.

    Two processes starting on one fresh SQLite file may race to create the tables; the loser retries
    and then finds the schema already at head. (PostgreSQL serialises them with an advisory lock.)
    """
    for attempt in range(retries + 1):
        try:
            _run(engine, command.upgrade, revision)
            break
        except DBAPIError as err:
            if attempt == retries:
                raise
            log.warning("migration attempt %d failed (%s); retrying", attempt + 1, err.__class__.__name__)
            time.sleep(0.2 * (attempt + 1))
    return current_revision(engine)


def downgrade(engine: Engine, revision: str = "-1") -> str | None:
    """Migrate down to ``revision`` ("base" empties the schema) and return the revision reached."""
    _run(engine, command.downgrade, revision)
    return current_revision(engine)
