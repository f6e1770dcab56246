"""The dashboard against a service with tokens, in a real headless Chromium (as tests/e2e/test_dashboard.py):
the page asks for the token when the API answers 401, keeps it in the tab's sessionStorage and sends it
on every request. Skipped only when no Chromium is installed."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from service.api import create_app
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store
from tests.e2e.browser import NEEDS_CHROMIUM, launch
from tests.e2e.processes import serve_in_thread

WRITE, READ = "dash-write-token", "dash-read-token"

pytestmark = [pytest.mark.e2e, NEEDS_CHROMIUM]


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[str, Store, int]]:

    store = open_store(f"sqlite:///{tmp_path / 'dash.db'}")
    n = 20
    store.write(
        FrameBatch(
            "arm",
            np.arange(n) * 0.01,
            ("j1",),
            np.zeros((n, 1)),
            ("i1",),
            np.zeros((n, 1, 3)),
            np.zeros((n, 1, 3)),
        )
    )
    alert = store.upsert_alert(
        "arm", "imu_dead", "imu:i1", {"kind": "imu_dead", "imu": "i1"}, "active", time.time()
    )
    settings = Settings(database_url="sqlite://", api_token=WRITE, api_read_token=READ)
    app = create_app(store, settings=settings)
    with serve_in_thread(app) as url:
        yield url, store, alert.id
    store.close()


def test_page_asks_for_the_token_and_sends_it(served: tuple[str, Store, int]) -> None:
    from playwright.sync_api import sync_playwright

    url, store, alert_id = served
    with sync_playwright() as p:
        browser = launch(p)
        page = browser.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        sent: list[str | None] = []
        page.on(
            "request", lambda r: sent.append(r.headers.get("authorization")) if "/api/v1/" in r.url else None
        )
        page.goto(url + "/")
        # reads need the read token: the prompt comes up, nothing is drawn
        page.wait_for_selector("#auth:not([hidden])", timeout=20_000)
        assert "needs an API token" in page.locator("#auth-message").inner_text()
        assert page.locator("article[data-robot='arm']").count() == 0
        page.fill("#auth-token", READ)
        page.click("#auth button")
        page.wait_for_selector("body[data-loaded='1']", timeout=20_000)
        page.wait_for_selector("#alerts tr[data-kind='imu_dead']", timeout=20_000)
        assert page.locator("#auth").is_hidden()
        assert page.evaluate("sessionStorage.getItem('bodyhealth-token')") == READ
        # the read token cannot ack: 401, the prompt says the token was refused, nothing changed
        page.click("#alerts tr[data-kind='imu_dead'] button")
        page.wait_for_selector("#auth:not([hidden])", timeout=10_000)
        assert "refused" in page.locator("#auth-message").inner_text()
        assert not store.alerts("arm")[0].acked
        page.fill("#auth-token", WRITE)
        page.click("#auth button")
        page.wait_for_selector("#alerts tr[data-kind='imu_dead'] button:not([disabled])", timeout=10_000)
        page.click("#alerts tr[data-kind='imu_dead'] button")
        page.wait_for_function(
            "document.querySelector(\"#alerts tr[data-kind='imu_dead']\").textContent.includes('acked')",
            timeout=10_000,
        )
        assert [a.acked for a in store.alerts("arm") if a.id == alert_id] == [True]
        # a reload in the same tab keeps the token: no prompt
        page.reload()
        page.wait_for_selector("body[data-loaded='1']", timeout=20_000)
        assert page.locator("#auth").is_hidden()
        assert sent[0] is None and f"Bearer {READ}" in sent and sent[-1] == f"Bearer {WRITE}"
        assert errors == []
        browser.close()
