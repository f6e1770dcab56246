"""The dashboard's monitoring answer in a real headless Chromium, against a real store (SQLite and
PostgreSQL): a robot whose data several trees fit is shown *undetermined* (amber, never green) with how
many trees fit, which joints to move to decide and its IMU-to-encoder skew; a robot whose unique body
matches its baseline is *healthy*; one with an active alert is *damaged*. With
BODYHEALTH_UPDATE_SCREENSHOT=1 the page goes to docs/dashboard.png."""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bodyschema.estimate import topology_from_dependency
from bodyschema.topology import Topology
from service.api import create_app
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store
from tests.e2e.browser import NEEDS_CHROMIUM, SCREENSHOT
from tests.e2e.processes import serve_in_thread

pytestmark = [pytest.mark.e2e, pytest.mark.slow, NEEDS_CHROMIUM]

JOINTS = ["j1", "j2", "j3"]
FULL = topology_from_dependency(
    np.array([[1, 0, 0], [1, 1, 0], [1, 1, 1]]), ["imu0", "imu1", "imu2"], JOINTS, method="fast"
)
# j2's link carries no IMU: two trees fit. Encoders and IMUs on separate clocks, 12.5 ms apart.
SPARSE = dataclasses.replace(
    topology_from_dependency(np.array([[1, 0, 0], [1, 1, 1]]), ["imu0", "imu2"], JOINTS, method="fast"),
    timing={
        "lag_ms": 14.25,
        "lag_unc_ms": 0.31,
        "skew_ms": 12.5,
        "drift_ppm": 0.0,
        "band_hz": 10.0,
        "at_s": 0.4,
    },
)
SPARSE_TRUE = Topology({"j1": None, "j2": "j1", "j3": "j2"}, {"imu0": "j1", "imu2": "j3"}, method="fast")
GREEN = "rgb(46, 125, 50)"
AMBER = "rgb(240, 180, 41)"
RED = "rgb(208, 52, 44)"


def _frames(store: Store, robot: str, imus: list[str]) -> None:
    n = 50
    store.write(
        FrameBatch(
            robot,
            np.arange(n) * 0.01,
            tuple(JOINTS),
            np.zeros((n, 3)),
            tuple(imus),
            np.full((n, len(imus), 3), 9.81),
            np.zeros((n, len(imus), 3)),
        )
    )


@pytest.fixture
def served(e2e_db_url: str) -> Iterator[tuple[str, Store]]:

    store = open_store(e2e_db_url)
    now = time.time()
    _frames(store, "sparse-arm", ["imu0", "imu2"])
    store.save_topology("sparse-arm", SPARSE_TRUE, now - 10, 0.49)
    store.set_baseline("sparse-arm", SPARSE_TRUE, "operator")
    store.save_topology("sparse-arm", SPARSE, now, 0.49)
    for robot in ("full-arm", "broken-arm"):
        _frames(store, robot, ["imu0", "imu1", "imu2"])
        store.save_topology(robot, FULL, now - 10, 0.49)
        store.set_baseline(robot, FULL, "auto")
        store.save_topology(robot, FULL, now, 0.49)
    trained = dataclasses.replace(
        FULL,
        method="network",
        training={"epochs": 24.0, "converged": 1.0, "loss": 0.011, "warm": 1.0},
        seconds=21.5,
    )
    store.save_topology("full-arm", trained, now - 5, 0.49)
    store.upsert_alert(
        "broken-arm",
        "imu_dead",
        "imu:imu1",
        {"kind": "imu_dead", "imu": "imu1", "detail": "frozen"},
        "active",
        now,
    )
    store.heartbeat("worker", now)
    app = create_app(store, settings=Settings(database_url="sqlite://"))
    with serve_in_thread(app) as url:
        yield url, store
    store.close()


def test_status_shown_per_robot(browser: Any, served: tuple[str, Store], tmp_path: Path) -> None:
    url, store = served
    page = browser.new_page(viewport={"width": 1300, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url + "/")
    page.wait_for_selector("body[data-loaded='1']", timeout=20_000)
    page.wait_for_selector("article[data-robot='sparse-arm'] svg[data-tree='current']", timeout=20_000)

    def card(robot: str) -> Any:
        return page.locator(f"article[data-robot='{robot}']")

    def verdict_color(robot: str) -> str:
        return card(robot).locator(".verdict").evaluate("e => getComputedStyle(e).backgroundColor")

    # several trees fit: undetermined, amber, with the count, the joints to move and the skew
    sparse = card("sparse-arm")
    assert sparse.get_attribute("data-status") == "undetermined"
    assert sparse.locator(".verdict").inner_text() == "undetermined"
    assert verdict_color("sparse-arm") == AMBER
    assert sparse.locator(".trees-fit").inner_text() == "2 trees fit the data"
    assert sparse.locator(".decide").inner_text() == (
        "to decide, move each on its own with the others still: j1, j2, j3"
    )
    assert sparse.locator(".skew").inner_text() == (
        "IMU-to-encoder skew 12.5 ± 0.3 ms at device time 0 s (IMU lag 14.3 ms), drift 0 ppm"
    )
    # the reasons, without repeating the joints to move
    (reason,) = sparse.locator(".reasons li").all_inner_texts()
    assert reason.startswith("2 trees fit the data; they differ in joint j2 (parent j1 or j3)")
    # nothing green on it, and its current tree says it is one of two
    assert sparse.locator(".verdict.healthy, [data-status='healthy']").count() == 0
    assert "one of 2 trees that fit" in sparse.locator("svg[data-tree='current'] + figcaption").inner_text()
    # unique and matching: healthy, green, no skew line (one clock)
    full = card("full-arm")
    assert full.get_attribute("data-status") == "healthy"
    assert full.locator(".verdict").inner_text() == "healthy"
    assert verdict_color("full-arm") == GREEN
    assert full.locator(".reasons li").all_inner_texts() == [
        "one tree fits the data, every joint is placed, and it matches the baseline"
    ]
    assert full.locator(".skew").count() == 0 and full.locator(".decide").count() == 0
    # the newest network retrain: how it started and trained, its cost, and whether it agrees
    net = full.locator(".network").inner_text()
    assert net.startswith("network retrain ") and net.endswith(
        ": warm start, 24 epochs, converged, 21.5 CPU s, same body as the screen"
    ), net
    assert card("broken-arm").locator(".network").count() == 0
    # an active alert: damaged, red
    broken = card("broken-arm")
    assert broken.locator(".verdict").inner_text() == "damaged"
    assert verdict_color("broken-arm") == RED
    assert broken.locator(".reasons li").all_inner_texts() == [
        "1 active alert: imu_dead on imu:imu1 (frozen)"
    ]
    summary = page.locator("#summary .verdict").all_inner_texts()
    assert summary == ["1 damaged", "1 undetermined", "1 healthy"]
    # The documentation's screenshot (one robot of each status) is refreshed on request or when
    # missing, so a test run leaves the working tree as it found it.
    shot = tmp_path / "dashboard.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 10_000
    if os.environ.get("BODYHEALTH_UPDATE_SCREENSHOT") or not SCREENSHOT.exists():
        SCREENSHOT.write_bytes(shot.read_bytes())
    # the answer follows the store: once one tree fits again and it matches, the robot turns healthy
    store.save_topology("sparse-arm", SPARSE_TRUE, time.time() + 1, 0.5)
    page.wait_for_selector("article[data-robot='sparse-arm'][data-status='healthy']", timeout=10_000)
    assert sparse.locator(".trees-fit").count() == 0
    assert page.locator("#summary .verdict").all_inner_texts() == ["1 damaged", "2 healthy"]
    assert errors == []
    page.close()


def test_undetermined_robot_offers_its_excitation_plan(browser: Any, served: tuple[str, Store]) -> None:
    """Beside the joints to move, an undetermined robot's card links the plan of that motion; the link
    downloads it as CSV (a time column, then one column of positions per joint); a robot the data
    decide has no such link."""
    url, _ = served
    page = browser.new_page(viewport={"width": 1300, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url + "/")
    link = page.locator("article[data-robot='sparse-arm'] .verdict-detail a.excitation-plan")
    link.wait_for(timeout=20_000)
    assert link.inner_text() == "download the excitation plan (CSV)"
    assert link.get_attribute("href") == "/api/v1/robots/sparse-arm/excitation?format=csv"
    page.wait_for_selector("article[data-robot='full-arm'][data-status='healthy']", timeout=20_000)
    assert page.locator("article[data-robot='full-arm'] a.excitation-plan").count() == 0
    assert page.locator("article[data-robot='broken-arm'] a.excitation-plan").count() == 0
    with page.expect_download(timeout=20_000) as download:
        link.click()
    saved = download.value
    assert saved.suggested_filename == "sparse-arm-excitation.csv"
    header, *rows = Path(saved.path()).read_text().splitlines()
    assert header.split(",") == ["time", *JOINTS]
    table = np.array([[float(x) for x in r.split(",")] for r in rows])
    # the route's default plan: 30 s at 100 Hz, from rest at the start pose and back
    assert table.shape == (3001, 1 + len(JOINTS))
    assert np.allclose(np.diff(table[:, 0]), 0.01) and table[0, 0] == 0.0
    q = table[:, 1:]
    assert np.allclose(q[0], q[-1], atol=1e-9)
    assert (np.ptp(q, axis=0) > 0.1).all()  # every joint the reasons name moves
    assert errors == []
    page.close()
