"""The whole service as a process: ``bodyhealth serve --demo`` at 20× real time, and what its test
checks (:func:`check_demo`), shared by tests/e2e/test_serve.py (SQLite) and
tests/e2e/test_serve_postgres.py (PostgreSQL), which the suite's workers run side by side.

Baselines are learned for every robot and must equal each robot's true body (every joint's parent,
every IMU's joint, unique); then damages are injected in turn into ``paper-3-1`` over the REST API,
and an active alert must name the kind and the part, with no alert of another kind or part raised on
the way (``MAX_CYCLES`` says how many worker cycles it may take; :data:`PG_KINDS` splits the kinds
over the two runs). The other robots stay undamaged and must not raise a single alert during the whole
run. SIGTERM ends it with exit code 0.
"""

from __future__ import annotations

import os
import re
import signal
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx

from simulators.robot import Robot
from tests.e2e.processes import start_service
from tests.waits import cpu_bound

__all__ = ["DAMAGES", "PG_KINDS", "Service", "check_dashboard", "check_demo", "demo_service"]

DAMAGED = "paper-3-1"
HEALTHY = ("ur5e-1", "quadruped-1")
#: (kind, request body, expected part). paper-3: j1 -> j2 -> {j3, j4, j5}, 12 IMUs per link
#: (imu0-11 on j1's link, imu12-23 on j2's, ...); the joint damages hit three sibling leaves so no
#: damage hides another.
DAMAGES: list[tuple[str, dict[str, Any], str]] = [
    ("imu_moved", {"imu": "imu0", "to": "j2"}, "imu:imu0"),
    ("imu_detached", {"imu": "imu13"}, "imu:imu13"),
    ("imu_dead", {"imu": "imu14"}, "imu:imu14"),
    ("encoder_fault", {"joint": "j3"}, "joint:j3"),
    ("joint_locked", {"joint": "j4"}, "joint:j4"),
    ("link_lost", {"joint": "j5"}, "joint:j5"),
]

#: Kinds the PostgreSQL run injects (an IMU's damage and a joint's); the SQLite run, with the geometry's
#: estimates on, injects the other four. So each kind passes the whole process once, the two runs side
#: by side on the suite's workers; every kind on every robot through the worker's real cycle is the
#: damage suite's (tests/service/test_damage_worker*.py).
PG_KINDS = ("imu_detached", "link_lost")

#: Worker cycles within which each alert must come. Each cycle at 20x speed and a 2 s interval sees a
#: fresh 20 s window, so a straddling window plus M = 2 makes 3 on an idle machine; but the farm paces
#: device time against the wall clock and the worker's interval is wall time, so on a loaded machine
#: (the suite beside other work) cycles cover uneven device time and the count wanders (seen: 5 for
#: ``link_lost``). What this test holds is the kind and part of the first alert; latency in device
#: time is the damage suite's (tests/service/test_damage_worker*.py). So the cycle count here is a
#: sanity ceiling, not a latency target: 24 cycles for every kind (seen: up to 14 for ``encoder_fault``
#: on PostgreSQL in a fresh-clone run, where the faster estimator packs more cycles into the same
#: device time). ``joint_locked`` on the robot preset is the slowest: the locked joint yields under its
#: commanded torque by more than two encoder steps now and then, restarting the still stretch the lock
#: is judged on (seen: 3, 8 and 16 cycles).
MAX_CYCLES: dict[str, int] = {}
DEFAULT_MAX_CYCLES = 24


def raised(service: Service) -> set[tuple[str, str]]:
    """(kind, part) of every alert the damaged robot has raised (active or resolved; pending is not
    raised)."""
    alerts = service.get(f"/api/v1/robots/{DAMAGED}/alerts")
    return {(a["kind"], a["part"]) for a in alerts if a["state"] != "pending"}


class Service:
    """``bodyhealth serve --demo`` at 20× in a process of its own, with a client on its API."""

    def __init__(self, tmp: Path, db_url: str, geometry: bool = True) -> None:
        self.err_path = tmp / "serve.err"
        env = {
            **os.environ,
            "BODYHEALTH_WORKER_INTERVAL_SECONDS": "2",
            "BODYHEALTH_WINDOW_SECONDS": "20",
            "BODYHEALTH_ALERT_HYSTERESIS_M": "2",
            "BODYHEALTH_BASELINE_REPEAT_K": "3",
            **({} if geometry else {"BODYHEALTH_KINEMATICS_INTERVAL_CYCLES": "0"}),
        }
        self.proc, self.url = start_service(
            db_url, "--demo", "--speed", "20", err=self.err_path, env=env, cwd=tmp
        )
        self.client = httpx.Client(base_url=self.url, timeout=10)

    def log_tail(self) -> str:
        return self.err_path.read_text()[-4000:]

    def get(self, path: str, **kw: Any) -> Any:
        r = self.client.get(path, **kw)
        r.raise_for_status()
        return r.json()

    def cycles(self) -> int:
        text = self.client.get("/metrics").text
        m = re.search(r"^bodyhealth_worker_cycles_total (\S+)$", text, re.M)
        return int(float(m.group(1))) if m else 0


#: Idle-machine seconds of the service's phases, stretched by the load (:func:`tests.waits.cpu_bound`):
#: readiness, every robot's baseline, one damage's alert, the stop after SIGTERM.
READY_S, BASELINES_S, ALERT_S, STOP_S = 90.0, 180.0, 120.0, 60.0


@contextmanager
def demo_service(db_url: str, tmp_path: Path, geometry: bool = True) -> Iterator[Service]:
    """The demo service on ``db_url``, killed on the way out if it is still running; ``geometry``
    False turns the geometry's estimates off (about half the service's CPU time on these robots)."""
    svc = Service(tmp_path, db_url, geometry)
    try:
        yield svc
    finally:
        if svc.proc.poll() is None:
            svc.proc.send_signal(signal.SIGKILL)
            svc.proc.wait(30)
        svc.client.close()


def wait_for(cond: Callable[[], Any], timeout: float, what: str, svc: Service, every: float = 0.3) -> Any:
    """``cond()``'s first truthy answer, asked every ``every`` seconds for ``timeout`` seconds; fails
    at once when the service died."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert svc.proc.poll() is None, f"service died while waiting for {what}:\n{svc.log_tail()}"
        try:
            got = cond()
        except httpx.HTTPError:
            got = None
        if got:
            return got
        time.sleep(every)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}\n{svc.log_tail()}")


def check_dashboard(service: Service, browser: Any, robots: list[dict], shot: Path) -> None:
    """The page on the demo: it draws each learned tree (current and baseline) with one node per joint, a
    damage injected from the page (``imu_dead`` on ``paper-3-1``'s imu30) becomes an alert row, pending
    then active, its IMU is marked changed, every robot shows one of the three statuses and the damaged
    one ``damaged``; a full-page screenshot goes to ``shot``."""
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    page.goto(service.url + "/")
    for r in robots:
        sel = f"article[data-robot='{r['name']}'] svg[data-tree='current'] circle.joint-node"
        page.wait_for_function(f'document.querySelectorAll("{sel}").length > 0', timeout=30_000)
        assert page.locator(sel).count() == len(r["joints"]), r["name"]
        base_sel = sel.replace("'current'", "'baseline'")
        assert page.locator(base_sel).count() == len(r["joints"]), r["name"]
    form = page.locator(f"article[data-robot='{DAMAGED}'] form.damage")
    form.locator("select").select_option("imu_dead")
    form.locator("input[name='part']").fill("imu30")
    form.locator("button").click()
    # pending at the first cycle that sees it, active after alert_hysteresis_m cycles: the same budget
    # as for the first sighting
    alert_ms = 1000 * cpu_bound(ALERT_S)
    row = "#alerts tr[data-kind='imu_dead'][data-part='imu:imu30']"
    page.wait_for_selector(row, timeout=alert_ms)
    page.wait_for_selector(row + "[data-state='active']", timeout=alert_ms)
    page.wait_for_selector(
        f"article[data-robot='{DAMAGED}'] rect.imu-node.changed[data-imu='imu30']", timeout=10_000
    )
    for r in robots:
        verdict = page.locator(f"article[data-robot='{r['name']}'] .verdict")
        assert verdict.inner_text() in ("healthy", "damaged", "undetermined"), r["name"]
    # an active alert makes the robot damaged (at the latest by the next poll)
    page.wait_for_selector(f"article[data-robot='{DAMAGED}'][data-status='damaged']", timeout=10_000)
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 10_000
    page.close()


def check_demo(
    service: Service,
    damages: list[tuple[str, dict[str, Any], str]],
    page: Callable[[list[dict]], None] | None = None,
) -> None:
    """The demo learns every robot's true body, raises each of ``damages`` (injected in turn) on its part
    with no other alert on the way and none on the healthy robots, and stops cleanly on SIGTERM.
    ``page``, given the robots, runs once the baselines are learned, before the damages (the
    dashboard's check, :func:`check_dashboard`, on the same process)."""
    assert re.fullmatch(r"http://127\.0\.0\.1:\d+", service.url)  # announced once bound
    t0 = time.monotonic()
    wait_for(lambda: service.get("/readyz"), cpu_bound(READY_S), "readiness", service)
    robots = wait_for(
        lambda: (
            (rs := service.get("/api/v1/robots"))
            and len(rs) == 3
            and all(r["has_baseline"] for r in rs)
            and rs
        ),
        cpu_bound(BASELINES_S),
        "baselines of all three robots",
        service,
    )
    print(f"baselines after {time.monotonic() - t0:.0f} s, {service.cycles()} worker cycles")
    assert {r["name"] for r in robots} == {DAMAGED, *HEALTHY}
    assert all(r["simulated"] for r in robots)
    for r in robots:  # the learned baseline is the true body: every joint's parent, every IMU's joint
        topo = service.get(f"/api/v1/robots/{r['name']}/topology")
        truth = Robot.from_catalog(r["name"].rsplit("-", 1)[0]).truth()
        learned = {j: v["parent"] for j, v in topo["baseline"]["joints"].items()}
        assert learned == truth.joint_parent, r["name"]
        assert topo["baseline"]["imus"] == truth.imu_joint, r["name"]
        assert topo["baseline"]["unique"] is True, r["name"]
        assert set(learned) == set(r["joints"]) and set(topo["baseline"]["imus"]) == set(r["imus"])

    if page is not None:
        page(robots)

    def no_alert_on_healthy() -> None:
        bad = [a for a in service.get("/api/v1/alerts") if a["robot"] in HEALTHY]
        assert bad == [], f"alerts on undamaged robots: {bad}"

    report = []
    for kind, body, part in damages:
        no_alert_on_healthy()
        before = raised(service)
        r = service.client.post(f"/api/v1/robots/{DAMAGED}/simulate/damage", json={"kind": kind, **body})
        assert r.status_code == 201, r.text
        truth = r.json()["truth"]["findings"][0]
        assert truth["kind"] == kind
        c0 = service.cycles()

        def alerted(kind: str = kind, part: str = part) -> bool:
            no_alert_on_healthy()
            return any(
                a["kind"] == kind and a["part"] == part
                for a in service.get(f"/api/v1/robots/{DAMAGED}/alerts", params={"active": "true"})
            )

        wait_for(alerted, cpu_bound(ALERT_S), f"an active {kind} alert on {part}", service)
        took = service.cycles() - c0
        report.append((kind, part, took))
        print(f"{kind} on {part}: alert after {took} worker cycles ({time.monotonic() - t0:.0f} s)")
        assert took <= MAX_CYCLES.get(kind, DEFAULT_MAX_CYCLES), f"{kind} on {part} took {took} cycles"
        # the first alert this damage raised is its own: no transient alert of another kind or part
        now = raised(service)
        extra = now - before - {(kind, part)}
        assert extra == set(), f"{kind}: alerts raised besides it: {extra}"
    print("cycles to alert:", report)
    no_alert_on_healthy()
    # the alerts are served the same way across robots, with the part split out
    active = service.get("/api/v1/alerts", params={"active": "true"})
    imu_damages = {(k, p) for k, _, p in DAMAGES[:3]} & {(k, p) for k, _, p in damages}
    assert {(a["kind"], a["part"]) for a in active} >= imu_damages
    assert all(a["robot"] == DAMAGED for a in active)
    service.proc.send_signal(signal.SIGTERM)
    assert service.proc.wait(cpu_bound(STOP_S)) == 0, service.log_tail()
    assert '"msg": "service stopped"' in service.err_path.read_text()
