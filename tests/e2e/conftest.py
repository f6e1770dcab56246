"""Whole-process tests use the same real databases as the service tests: SQLite files and PostgreSQL
databases made for the test (``tests/service/conftest.py`` owns the server and the cleanup)."""

from __future__ import annotations

from tests.service.conftest import new_pg_database, postgres_server

__all__ = ["new_pg_database", "postgres_server"]
