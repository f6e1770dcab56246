"""The runnable examples in the data layer's docstrings stay true."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = [
    "service.settings",
    "service.db.engine",
    "service.db.migrate",
    "service.store",
    "service.store.schema",
    "service.store.chunks",
    "service.ingest.pipeline",
    "service.ingest.replay",
    "service.ingest.farm",
    "service.ingest.spec",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name: str) -> None:
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
