"""``bodyhealth db``: the database schema step, by hand.

Opening a store never migrates (see :mod:`service.store.schema`): ``bodyhealth serve`` upgrades at
start, and everything else expects a database that is already at the newest revision. ``db upgrade``
takes that step on its own (before the first ingest, after installing a new version, on a copy to be
inspected), and ``db current`` tells where a database stands without changing it.
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "db",
        help="database schema: upgrade to the newest revision, or show the current one",
        description="Migrate the database (Alembic) or show its schema revision. The URL comes from "
        "--database-url or the settings (BODYHEALTH_DATABASE_URL).",
    )
    actions = p.add_subparsers(dest="db_action", required=True)
    up = actions.add_parser("upgrade", help="migrate the database to the newest schema revision")
    _url_option(up)
    up.set_defaults(func=_upgrade)
    cur = actions.add_parser("current", help="print the database's schema revision and the newest one")
    _url_option(cur)
    cur.set_defaults(func=_current)


def _url_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--database-url", help="SQLAlchemy URL (default: settings, sqlite:///./var/bodyhealth.db)")


def _upgrade(args: argparse.Namespace) -> int:
    from sqlalchemy.exc import SQLAlchemyError

    from service.store import Store

    store = Store(args.database_url)
    try:
        revision = store.upgrade()
    except SQLAlchemyError as err:
        return _failed(store.url, err)
    finally:
        store.close()
    print(f"{_shown(store.url)}: at revision {revision} (head)")
    return 0


def _current(args: argparse.Namespace) -> int:
    from sqlalchemy.exc import SQLAlchemyError

    from service.db.migrate import current_revision, head_revision
    from service.store import Store

    store = Store(args.database_url)
    try:
        current = None if _missing_sqlite_file(store.url) else current_revision(store.engine)
    except SQLAlchemyError as err:
        return _failed(store.url, err)
    finally:
        store.close()
    print(f"current: {current or 'none'}")
    print(f"head: {head_revision()}")
    return 0


def _missing_sqlite_file(url: str) -> bool:
    """True for an SQLite file that does not exist yet (looking must not create it)."""
    from pathlib import Path

    from sqlalchemy.engine import make_url

    u = make_url(url)
    db = u.database or ""
    memory = db in ("", ":memory:") or db.startswith("file:")
    return u.get_backend_name() == "sqlite" and not memory and not Path(db).expanduser().exists()


def _shown(url: str) -> str:
    from sqlalchemy.engine import make_url

    return make_url(url).render_as_string(hide_password=True)


def _failed(url: str, err: Exception) -> int:
    print(f"bodyhealth db: error: cannot use the database {_shown(url)}: {err}", file=sys.stderr)
    return 1
