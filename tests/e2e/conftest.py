"""Whole-process tests use the same real databases as the service tests: SQLite files and PostgreSQL
databases made for the test (``tests/service/conftest.py`` owns the server and the cleanup)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tests.service.conftest import new_pg_database, postgres_server

__all__ = ["e2e_db_url", "new_pg_database", "postgres_server"]


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def e2e_db_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """A store for a service process: its own SQLite file, or a PostgreSQL database made for the test."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'e2e.db'}"
    make: Callable[[], str] = request.getfixturevalue("new_pg_database")
    return make()
