"""Whole-process tests use the same real databases as the service tests: SQLite files and PostgreSQL
databases made for the test (``tests/service/conftest.py`` owns the server and the cleanup). The
dashboard tests share one headless Chromium per module (``browser``, tests/e2e/browser.py)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.e2e.browser import launch
from tests.service.conftest import new_pg_database, pg_cluster, postgres_server

__all__ = ["browser", "e2e_db_url", "new_pg_database", "pg_cluster", "postgres_server"]


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def e2e_db_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """A store for a service process: its own SQLite file, or a PostgreSQL database made for the test."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'e2e.db'}"
    make: Callable[[], str] = request.getfixturevalue("new_pg_database")
    return make()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """A headless Chromium for the module's pages (tests/e2e/browser.py)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = launch(p)
        yield b
        b.close()
