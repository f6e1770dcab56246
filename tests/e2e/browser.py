"""The headless Chromium of the dashboard tests: Debian's package (``make setup-browser``), driven by the
playwright package. The ``browser`` fixture (tests/e2e/conftest.py) launches it once per module."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

__all__ = ["ARGS", "CHROMIUM", "NEEDS_CHROMIUM", "SCREENSHOT", "launch"]

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
#: The dashboard's picture in the docs (tests/e2e/test_dashboard_status.py takes it).
SCREENSHOT = Path(__file__).resolve().parents[2] / "docs" / "dashboard.png"

#: The dashboard tests skip only when no Chromium is installed (a failure in CI, tests/conftest.py).
NEEDS_CHROMIUM = pytest.mark.skipif(
    not Path(CHROMIUM).exists() and shutil.which("chromium") is None,
    reason="Debian's chromium is not installed (make setup-browser installs it)",
)


def launch(playwright: Any) -> Any:
    """A headless Chromium (Debian's, with :data:`ARGS`) of ``playwright``, a started
    ``sync_playwright()``."""
    return playwright.chromium.launch(
        executable_path=CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium"), args=ARGS
    )
