"""The bounded alert path on a real store: a fast finding is pending at once, the sensor networks
confirm or withdraw it, or it stands unconfirmed after the timeout; a fast baseline is adopted when the
networks are late; alerts are judged again after a restart; an approval never waits for a cycle.

The clock is injected (wall time moves only when the test says) and the estimator scripted (the
topology each cycle is what the test says); signal health, the diff, the tracker and the store run for
real. Starved training is a queue whose retrains never finish (:class:`StalledQueue`).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bodyschema.recording import Recording
from service.api import create_app
from service.retrain import RetrainQueueEntry
from service.settings import Settings
from service.status import robot_status
from service.store import Store, open_store
from service.worker import Worker, next_wait
from tests.builders import synth
from tests.service.builders import GOOD, MOVED, ByMethod, feed


class StalledQueue:
    """A training queue on a machine that gives training no CPU: every retrain asked for waits, none
    finishes. Reports its entries as :meth:`service.retrain.RemoteRetrains.queue_status` does."""

    fault: str | None = None

    def __init__(self, expected_seconds: float) -> None:
        self.expected_seconds = expected_seconds
        self.wanted: dict[tuple[str, str], float] = {}

    def want(self, robot: str, method: str) -> None:
        self.wanted.setdefault((robot, method), 0.0)

    def collect(self, clock: object) -> None:
        return None

    def submit_wanted(self) -> None:
        return None

    def queue_status(self) -> list[RetrainQueueEntry]:
        return [
            RetrainQueueEntry(r, m, "waiting", k, since, self.expected_seconds, 0.0, None)
            for k, ((r, m), since) in enumerate(sorted(self.wanted.items()))
        ]


class Clock:
    """Wall time that moves when the test says; each step also brings the robot's next frames (a block
    of ``rec`` later in device time), so the robot is never idle."""

    def __init__(self, store: Store, rec: Recording, t: float = 1000.0) -> None:
        self.t, self.store, self.rec, self.offset = t, store, rec, 0.0
        self.feed()

    def __call__(self) -> float:
        return self.t

    def feed(self) -> None:
        self.offset = feed(self.store, self.rec, offset=self.offset)

    def step(self, dt: float = 5.0) -> None:
        self.t += dt
        self.feed()


@pytest.fixture
def sqlite_store(tmp_path: Path) -> Iterator[Store]:
    s = open_store(f"sqlite:///{tmp_path / 'a.db'}")
    yield s
    s.close()


@pytest.fixture
def settings() -> Settings:
    return Settings(
        database_url="sqlite://",
        window_seconds=10.0,
        baseline_repeat_k=3,
        alert_hysteresis_m=2,
        worker_interval_seconds=5.0,
        network_interval_cycles=1000,  # the networks on, never due on their schedule in a test
        kinematics_interval_cycles=0,
        baseline_unconfirmed_cycles=4,
        baseline_unconfirmed_seconds=5.0,
        confirm_timeout_max_seconds=120.0,
    )


def _baselined(store: Store, settings: Settings, rng: np.random.Generator) -> tuple[Worker, Clock]:
    """A worker whose robot got a fast-unconfirmed baseline: the networks never answered."""
    clock = Clock(store, synth(rng, seconds=12))
    w = Worker(store, settings, estimator=ByMethod(GOOD), clock=clock, remote=StalledQueue(30.0))
    for cycle in range(3):
        clock.step()
        assert not w.run_cycle()["arm"].baseline_set, cycle
    (wait,) = store.robot("arm").waiting["waits"]
    assert wait["what"].startswith("baseline: the sensor networks' answer") and wait["since"] == 1015.0
    clock.step()
    assert w.run_cycle()["arm"].baseline_set
    base = store.baseline("arm")
    assert base is not None and base.source == "fast-unconfirmed"
    assert robot_status(store, "arm").baseline_networks == "unconfirmed"
    return w, clock


def test_unconfirmed_baseline_waits_wall_time_not_slow_cycles(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    """On a loaded machine cycles are slow: the wait is counted in wall time, so 20 s cycles reach the
    60 s wait after 3 cycles past the streak, and 5 s cycles need 12 (not the 4-cycle minimum)."""
    for dt, cycles_after in ((20.0, 3), (5.0, 12)):
        store = open_store("sqlite://")
        s = settings.model_copy(update={"baseline_unconfirmed_seconds": 60.0})
        clock = Clock(store, synth(rng, seconds=12))
        w = Worker(store, s, estimator=ByMethod(GOOD), clock=clock, remote=StalledQueue(30.0))
        for _ in range(3):
            clock.step(dt)
            assert not w.run_cycle()["arm"].baseline_set
        for n in range(1, cycles_after + 1):
            clock.step(dt)
            assert w.run_cycle()["arm"].baseline_set == (n == cycles_after), (dt, n)
        store.close()


def test_a_short_window_after_a_restart_raises_nothing_and_the_next_full_one_judges(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    """The robot's clock went back (its controller restarted): the new epoch's first windows are short,
    and a finding on them rests on less than its thresholds were derived for. Nothing is raised until
    a full window (80 % of ``window_seconds``) shows it."""
    w, clock = _baselined(sqlite_store, settings, rng)
    w.estimator.next = MOVED
    after = synth(rng, seconds=12)
    short = after.t < 5.0
    part = Recording(
        t=after.t[short],
        joint_names=after.joint_names,
        q=after.q[short],
        imu_names=after.imu_names,
        acc=after.acc[short],
        gyro=after.gyro[short],
    )
    feed(sqlite_store, part)  # device time from 0 again: a new clock epoch of 5 s
    clock.t += 5.0
    r = w.run_cycle()["arm"]
    assert r.transitions == [] and sqlite_store.alerts("arm") == []
    rest = ~short
    feed(
        sqlite_store,
        Recording(
            t=after.t[rest],
            joint_names=after.joint_names,
            q=after.q[rest],
            imu_names=after.imu_names,
            acc=after.acc[rest],
            gyro=after.gyro[rest],
        ),
    )
    clock.t += 5.0
    r = w.run_cycle()["arm"]
    assert [(t.state, t.kind, t.part) for t in r.pending] == [("pending", "imu_moved", "imu:c1")]


def test_pending_at_once_then_unconfirmed_after_the_timeout(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    w, clock = _baselined(sqlite_store, settings, rng)
    w.estimator.next = MOVED
    clock.step()
    seen = clock.t
    r = w.run_cycle()["arm"]
    assert [(t.state, t.kind, t.part) for t in r.pending] == [("pending", "imu_moved", "imu:c1")]
    (a,) = sqlite_store.alerts("arm")
    assert (a.state, a.confirmed, a.note) == (
        "pending",
        None,
        "waiting for confirmation by the sensor networks",
    )
    st = robot_status(sqlite_store, "arm")
    assert st.status == "undetermined" and [p.id for p in st.pending] == [a.id]
    # derived timeout: 3 x the queue's 30 s expected retrain
    wait = next(x for x in st.waiting if x["what"] == "network confirmation of imu_moved imu:c1")
    assert (wait["since"], wait["until"]) == (seen, seen + 90.0)
    (entry,) = st.queue
    assert (entry["robot"], entry["method"], entry["state"]) == ("arm", "network", "waiting")
    assert entry["expected_finish"] == pytest.approx(seen + 30.0)
    clock.step(89.0)
    assert w.run_cycle()["arm"].transitions == []
    assert sqlite_store.alerts("arm")[0].state == "pending"
    clock.step(1.0)
    (tr,) = w.run_cycle()["arm"].transitions
    assert (tr.state, tr.confirmed) == ("active", False)
    (a,) = sqlite_store.alerts("arm", active=True)
    assert a.confirmed is False and a.note.startswith(
        "unconfirmed: the sensor networks did not answer within 90 s"
    )
    st = robot_status(sqlite_store, "arm")
    assert st.status == "damaged" and "unconfirmed by the sensor networks" in st.reasons[0]
    assert not any(x["what"].startswith("network confirmation") for x in st.waiting)


def test_a_stored_network_topology_confirms_or_withdraws(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    w, clock = _baselined(sqlite_store, settings, rng)
    w.estimator.next = MOVED
    clock.step()
    assert [t.state for t in w.run_cycle()["arm"].pending] == ["pending"]
    end = sqlite_store.latest_topology("arm", "fast").window_end_t
    # the networks answer on a window from after the finding: no change there
    sqlite_store.save_topology("arm", dataclasses.replace(GOOD, method="network"), clock.t, end)
    clock.step()
    (tr,) = w.run_cycle()["arm"].transitions
    assert tr.state == "resolved" and tr.note.startswith("withdrawn: the sensor networks' topology")
    (a,) = sqlite_store.alerts("arm")
    assert a.state == "resolved" and "no change of imu:c1" in a.note
    # they learn it later: pending again, then active and confirmed
    sqlite_store.save_topology("arm", dataclasses.replace(MOVED, method="network"), clock.t, 1e9)
    clock.step()
    assert [t.state for t in w.run_cycle()["arm"].pending] == ["pending"]
    clock.step()
    (tr,) = w.run_cycle()["arm"].transitions
    assert (tr.state, tr.confirmed, tr.note) == ("active", True, "confirmed by the sensor networks")
    (a,) = sqlite_store.alerts("arm", active=True)
    assert a.confirmed is True
    # a network body that differs as the open alert does is no contradiction of the baseline
    assert robot_status(sqlite_store, "arm").baseline_networks == "unconfirmed"


def test_networks_contradicting_a_fast_baseline_make_the_robot_undetermined(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    w, clock = _baselined(sqlite_store, settings, rng)
    assert robot_status(sqlite_store, "arm").status == "healthy"
    end = sqlite_store.baseline("arm").window_end_t
    sqlite_store.save_topology("arm", dataclasses.replace(MOVED, method="network"), clock.t, end)
    st = robot_status(sqlite_store, "arm")
    assert (st.status, st.baseline_networks) == ("undetermined", "contradicted")
    assert any("contradicted by the sensor networks" in r for r in st.reasons)
    clock.step()
    w.run_cycle()
    waits = sqlite_store.robot("arm").waiting["waits"]
    assert [x["what"][:34] for x in waits] == ["baseline: an operator's approval ("]


def test_approve_baseline_returns_while_a_cycle_holds_the_lock(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    w, clock = _baselined(sqlite_store, settings, rng)
    w.estimator.next = MOVED
    for dt in (5.0, 90.0):  # pending, then active unconfirmed
        clock.step(dt)
        w.run_cycle()
    assert len(sqlite_store.alerts("arm", active=True)) == 1
    held, release = threading.Event(), threading.Event()

    def long_cycle() -> None:
        with w._cycle_lock:
            held.set()
            release.wait()

    t = threading.Thread(target=long_cycle)
    t.start()
    try:
        assert held.wait(30)
        base = w.approve_baseline("arm")  # one store transaction; would block here on the lock
        assert sqlite_store.baseline("arm").id == base.id and base.source == "operator"
        (a,) = sqlite_store.alerts("arm")
        assert (a.state, a.note) == ("resolved", "a new baseline was approved")
    finally:
        release.set()
        t.join()
    clock.step()
    r = w.run_cycle()["arm"]  # the new baseline is the moved body: nothing against it
    assert r.diff.findings == () and r.transitions == [] and w.tracker.active("arm") == []


def test_a_restart_judges_old_alerts_on_the_first_full_window(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    w, clock = _baselined(sqlite_store, settings, rng)
    w.estimator.next = MOVED
    for dt in (5.0, 90.0):  # pending, then active unconfirmed
        clock.step(dt)
        w.run_cycle()
    assert len(sqlite_store.alerts("arm", active=True)) == 1
    # restarted; the body is the baseline's again: resolved on the first window, not M cycles later
    w2 = Worker(sqlite_store, settings, estimator=ByMethod(GOOD), clock=clock, remote=StalledQueue(30.0))
    clock.step()
    (tr,) = w2.run_cycle()["arm"].transitions
    assert (tr.state, tr.part) == ("resolved", "imu:c1")
    assert tr.note == "not seen in the first full window after the service restarted"
    assert sqlite_store.alerts("arm", active=True) == []


def test_a_restart_keeps_an_alert_the_first_window_still_shows(
    sqlite_store: Store, settings: Settings, rng: np.random.Generator
) -> None:
    w, clock = _baselined(sqlite_store, settings, rng)
    w.estimator.next = MOVED
    clock.step()
    w.run_cycle()
    (a,) = sqlite_store.alerts("arm")
    assert a.state == "pending"
    w2 = Worker(sqlite_store, settings, estimator=ByMethod(MOVED), clock=clock, remote=StalledQueue(30.0))
    # the pending alert's wait counts from when it was first seen; the new process's queue knows no
    # retrain time yet, so it waits the stated maximum
    clock.step(settings.confirm_timeout_max_seconds)
    (tr,) = w2.run_cycle()["arm"].transitions
    assert (tr.state, tr.confirmed) == ("active", False)
    assert [x.id for x in sqlite_store.alerts("arm", active=True)] == [a.id]


def test_readyz_reports_a_slow_worker_as_degraded_and_a_dead_one_as_not_ready(
    sqlite_store: Store, settings: Settings
) -> None:
    w = Worker(sqlite_store, settings.model_copy(update={"worker_interval_seconds": 3600.0}))
    app = create_app(sqlite_store, settings=settings, worker=w)
    with TestClient(app) as c:
        w.start()
        try:
            deadline = time.monotonic() + 30.0  # an empty store's cycle takes milliseconds
            while w.progress()["since_last_cycle_s"] is None and time.monotonic() < deadline:
                time.sleep(0.01)
            sqlite_store.heartbeat("worker", time.time() - 600.0)  # as a cycle stretched by load
            r = c.get("/readyz")
            assert r.status_code == 200, r.json()
            assert r.json()["degraded"][0].startswith("worker slow: heartbeat 60")
            assert r.json()["checks"]["worker_lag"]["interval_s"] == 3600.0
        finally:
            w.stop()
        r = c.get("/readyz")
        assert r.status_code == 503 and "worker thread not running" in r.json()["reasons"]


@pytest.mark.parametrize(
    ("elapsed", "want"),
    [(0.5, 4.5), (4.5, 5.5), (7.0, 3.0), (14.2, 5.8)],
)
def test_a_cycle_that_overran_skips_missed_ticks_after_a_rest(elapsed: float, want: float) -> None:
    wait = next_wait(elapsed, 5.0, 1.0)
    assert wait == pytest.approx(want) and wait >= 1.0
    assert (elapsed + wait) % 5.0 == pytest.approx(0.0, abs=1e-9)
