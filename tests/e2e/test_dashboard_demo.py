"""The dashboard on the whole demo daemon: ``serve --demo`` at 20×, the page draws each learned tree, a
damage injected from the page becomes an alert (tests/e2e/test_dashboard.py has the page on a served
store; this one, the slowest, runs beside it on another of the suite's workers)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from tests.e2e.browser import NEEDS_CHROMIUM
from tests.e2e.processes import start_service
from tests.waits import cpu_bound

pytestmark = [pytest.mark.e2e, pytest.mark.slow, NEEDS_CHROMIUM]


def test_demo_dashboard_draws_every_robot_and_shows_an_injected_damage(
    browser: Any, tmp_path: Path, e2e_db_url: str
) -> None:
    """The real thing: ``serve --demo`` at 20×, the page draws each learned tree with one node per joint,
    a damage injected from the page becomes an alert row, and every robot shows one of the three
    statuses. (docs/dashboard.png comes from tests/e2e/test_dashboard_status.py, which shows one robot
    of each status.)"""
    import os
    import signal

    import httpx

    env = {
        **os.environ,
        "BODYHEALTH_WORKER_INTERVAL_SECONDS": "2",
        "BODYHEALTH_WINDOW_SECONDS": "20",
        "BODYHEALTH_BASELINE_REPEAT_K": "2",
    }
    proc, url = start_service(
        e2e_db_url, "--demo", "--speed", "20", err=tmp_path / "serve.err", env=env, cwd=tmp_path
    )
    try:
        deadline = time.monotonic() + cpu_bound(240.0)
        robots: list[dict] = []
        while time.monotonic() < deadline:
            assert proc.poll() is None, (tmp_path / "serve.err").read_text()[-3000:]
            try:
                robots = httpx.get(url + "/api/v1/robots", timeout=5).json()
            except httpx.HTTPError:
                robots = []
            if len(robots) == 3 and all(r["has_baseline"] for r in robots):
                break
            time.sleep(0.5)
        assert len(robots) == 3 and all(r["has_baseline"] for r in robots), robots
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.goto(url + "/")
        for r in robots:
            sel = f"article[data-robot='{r['name']}'] svg[data-tree='current'] circle.joint-node"
            page.wait_for_function(f'document.querySelectorAll("{sel}").length > 0', timeout=30_000)
            assert page.locator(sel).count() == len(r["joints"]), r["name"]
            base_sel = sel.replace("'current'", "'baseline'")
            assert page.locator(base_sel).count() == len(r["joints"]), r["name"]
        form = page.locator("article[data-robot='paper-3-1'] form.damage")
        form.locator("select").select_option("imu_dead")
        form.locator("input[name='part']").fill("imu30")
        form.locator("button").click()
        alert_ms = 1000 * cpu_bound(120.0)
        # pending at the first cycle that sees it, active after alert_hysteresis_m cycles (2 here, 2 s
        # apart on an idle machine): the same budget as for the first sighting
        page.wait_for_selector("#alerts tr[data-kind='imu_dead'][data-part='imu:imu30']", timeout=alert_ms)
        page.wait_for_selector(
            "#alerts tr[data-kind='imu_dead'][data-part='imu:imu30'][data-state='active']", timeout=alert_ms
        )
        page.wait_for_selector(
            "article[data-robot='paper-3-1'] rect.imu-node.changed[data-imu='imu30']", timeout=10_000
        )
        for r in robots:
            verdict = page.locator(f"article[data-robot='{r['name']}'] .verdict")
            assert verdict.inner_text() in ("healthy", "damaged", "undetermined"), r["name"]
        # an active alert makes the robot damaged (at the latest by the next poll)
        page.wait_for_selector("article[data-robot='paper-3-1'][data-status='damaged']", timeout=10_000)
        shot = tmp_path / "dashboard.png"
        page.screenshot(path=str(shot), full_page=True)
        assert shot.stat().st_size > 10_000
        page.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(cpu_bound(60.0))
    assert rc == 0
