"""The dashboard in a real headless Chromium (Debian's package, driven by the playwright package).

Two levels: the page against an in-process server on a prepared store (trees, highlights, alerts, the
damage form, ack), and the whole demo daemon where a damage injected from the page becomes an alert
(tests/e2e/test_serve.py, on SQLite as ``make run`` serves it). The first runs on SQLite and on
PostgreSQL: the page reads what the store gives back, and the two backends must give back the same
trees, alerts and acks. Skipped only when no Chromium is installed.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from bodyschema.topology import Topology
from service.api import create_app
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store
from tests.e2e.browser import NEEDS_CHROMIUM
from tests.e2e.processes import serve_in_thread
from tests.service.geometry import geometry_json

pytestmark = [pytest.mark.e2e, pytest.mark.slow, NEEDS_CHROMIUM]


BASE = Topology(
    {"j1": None, "j2": "j1", "j3": "j2", "j4": "j1"},
    {"i1": "j1", "i2": "j2", "i3": "j3", "i4": "j3", "i5": "j4"},
    method="fast",
)
CUR = Topology(
    {"j1": None, "j2": "j1", "j3": "j2", "j4": "j1"},
    {"i1": "j1", "i2": "j2", "i3": "j3", "i4": "j4", "i5": "j4"},
    method="fast",
)


class RecordingFarm:
    """Records the damage the page asked for, as the farm would, and answers its ground truth."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, dict]] = []

    def simulates(self, robot: str) -> bool:
        return robot == "arm"

    def apply_damage(self, robot: str, kind: str, params: dict) -> dict:
        params = dict(params)
        self.calls.append((robot, kind, params))
        return {
            "changed": True,
            "findings": [{"kind": kind, "imu": params.get("imu", "i2"), "confidence": 1.0}],
        }


@pytest.fixture
def served(e2e_db_url: str) -> Iterator[tuple[str, Store, RecordingFarm]]:

    store = open_store(e2e_db_url)
    n = 50
    for robot in ("arm", "leg"):
        store.write(
            FrameBatch(
                robot,
                np.arange(n) * 0.01,
                ("j1", "j2", "j3", "j4"),
                np.zeros((n, 4)),
                ("i1", "i2", "i3", "i4", "i5"),
                np.full((n, 5, 3), 9.81),
                np.zeros((n, 5, 3)),
            )
        )
        store.save_topology(robot, BASE, time.time() - 10, 0.49)
        base_id = store.set_baseline(robot, BASE, "auto")
    # leg's geometry: learned under its baseline, then an estimate in which i2's axis turned
    # (with the lever arms of 3 estimates pooled under the baseline and of 2 newest)
    arms = [{"i1": [0.1, 0.0, 0.0]}]
    first = {**geometry_json(BASE), "lever_arm_pool": arms * 3}
    store.save_kinematics("leg", base_id, first, wall_time=time.time() - 5)
    turned = {**geometry_json(BASE, {"i2": [0.0, 1.0, 0.0]}), "lever_arm_pool": arms * 2}
    store.save_kinematics("leg", base_id, turned, wall_time=time.time(), latest=True)
    store.save_topology("arm", CUR, time.time(), 0.49)
    store.mark_simulated("arm", "toy")
    store.upsert_alert(
        "arm",
        "imu_moved",
        "imu:i4",
        {"kind": "imu_moved", "imu": "i4", "from": "j3", "to": "j4"},
        "active",
        time.time(),
    )
    store.heartbeat("worker", time.time())
    inj = RecordingFarm()
    app = create_app(store, settings=Settings(database_url="sqlite://"), damage=inj)
    with serve_in_thread(app) as url:
        yield url, store, inj
    store.close()


def test_trees_alerts_and_damage_form(browser: Any, served: tuple[str, Store, RecordingFarm]) -> None:
    url, store, inj = served
    page = browser.new_page(viewport={"width": 1300, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url + "/")
    page.wait_for_selector("body[data-loaded='1']", timeout=20_000)
    page.wait_for_selector("article[data-robot='leg'] svg[data-tree='current']", timeout=20_000)
    for robot in ("arm", "leg"):
        for tree in ("baseline", "current"):
            nodes = page.locator(f"article[data-robot='{robot}'] svg[data-tree='{tree}'] circle.joint-node")
            assert nodes.count() == 4, (robot, tree)
        assert (
            page.locator(f"article[data-robot='{robot}'] svg[data-tree='current'] rect.imu-node").count() == 5
        )
    # the moved IMU is red in arm's trees, nothing is red on leg
    assert (
        page.locator("article[data-robot='arm'] svg[data-tree='current'] rect.imu-node.changed").count() == 1
    )
    assert page.locator("article[data-robot='arm'] rect.imu-node.changed[data-imu='i4']").count() == 2
    assert page.locator("article[data-robot='leg'] .changed").count() == 0
    # the active alert makes arm damaged; leg's unique body matches its baseline
    assert page.locator("article[data-robot='arm'] .verdict").inner_text() == "damaged"
    assert page.locator("article[data-robot='leg'] .verdict").inner_text() == "healthy"
    row = page.locator("#alerts tr[data-kind='imu_moved']")
    assert row.count() == 1 and "imu:i4" in row.inner_text() and "j3 → j4" in row.inner_text()
    # only the simulated robot has the damage control; using it posts to the API
    assert page.locator("article[data-robot='leg'] form.damage").count() == 0
    form = page.locator("article[data-robot='arm'] form.damage")
    result = "document.querySelector(\"article[data-robot='arm'] form.damage .result\").textContent"
    form.locator("select").select_option("imu_dead")
    assert not form.locator("input[name='magnitude']").is_visible()  # a topology damage has no size
    form.locator("input[name='part']").fill("i2")
    form.locator("button").click()
    page.wait_for_function(f"{result}.startsWith('injected')", timeout=10_000)
    assert inj.calls == [("arm", "imu_dead", {"imu": "i2"})]
    # a geometry drift takes its magnitude, in the unit shown (mm for a slide, sent in metres)
    for kind, size, sent in (
        ("imu_rotated", "2.5", {"angle_deg": 2.5}),
        ("imu_shifted", "5", {"meters": 0.005}),
    ):
        page.evaluate(f"{result} = ''")
        form.locator("select").select_option(kind)
        assert form.locator("input[name='magnitude']").is_visible()
        form.locator("input[name='part']").fill("i3")
        form.locator("input[name='magnitude']").fill(size)
        form.locator("button").click()
        page.wait_for_function(f"{result}.startsWith('injected')", timeout=10_000)
        assert inj.calls[-1] == ("arm", kind, {"imu": "i3", **sent})
    # geometry: leg's turned IMU is named and its row is red; arm has none learned yet
    leg = page.locator("article[data-robot='leg'] .geometry")
    page.wait_for_selector("article[data-robot='leg'] .geometry[data-drift='1']", timeout=10_000)
    assert "drift: imu_rotated i2" in leg.locator("summary").inner_text()
    assert "5/5 IMUs converged" in leg.locator("summary").inner_text()
    leg.locator("summary").click()
    assert leg.locator("tr[data-imu]").count() == 5
    assert leg.locator("tr.drifted[data-imu='i2']").count() == 1 and leg.locator("tr.drifted").count() == 1
    assert "(0.000, 1.000, 0.000)" in leg.locator("tr[data-imu='i2']").inner_text()
    assert "(100.0, 0.0, 0.0)" in leg.locator("tr[data-imu='i1']").inner_text()
    assert (
        "pooled lever arms: 3 estimates under the baseline, 2 newest" in leg.locator(".pooled").inner_text()
    )
    assert "not learned yet" in page.locator("article[data-robot='arm'] .geometry").inner_text()
    # an alert that appears in the store shows up at the next poll; ack works from the page
    store.upsert_alert("arm", "imu_dead", "imu:i2", {"kind": "imu_dead", "imu": "i2"}, "active", time.time())
    page.wait_for_selector("#alerts tr[data-kind='imu_dead']", timeout=10_000)
    page.locator("#alerts tr[data-kind='imu_dead'] button").click()
    page.wait_for_function(
        "document.querySelector(\"#alerts tr[data-kind='imu_dead']\").textContent.includes('acked')",
        timeout=10_000,
    )
    assert [a.acked for a in store.alerts("arm", active=True) if a.kind == "imu_dead"] == [True]
    # an operator approves the current body of "arm": its baseline becomes CUR, its alerts resolve
    page.on("dialog", lambda d: d.accept())
    page.locator("article[data-robot='arm'] button.approve").click()
    page.wait_for_function(
        "document.querySelector(\"article[data-robot='arm'] .ops .result\")"
        ".textContent.startsWith('baseline set')",
        timeout=10_000,
    )
    assert store.baseline("arm").source == "operator"
    assert store.baseline("arm").topology.imu_joint["i4"] == "j4"
    page.wait_for_function("document.querySelectorAll('#alerts tr.alert').length === 0", timeout=10_000)
    page.wait_for_selector("article[data-robot='arm'][data-status='healthy']", timeout=10_000)
    assert errors == []
    page.close()
