"""A robot whose device clock goes back (a restart) starts a new epoch: its new frames are kept, the old
epoch ages out, the worker analyses the current epoch, and alerts resolve. On SQLite and PostgreSQL.

Without epochs the new frames lie before everything stored: the prune drops them against the old run's
newest stamp, the window stays the old run's last one, and an alert raised there never resolves. Each
test below fails that way.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bodyschema.recording import Recording
from service.api import create_app
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store
from service.worker import Worker
from tests.builders import synth
from tests.service.builders import GOOD, Scripted, feed

#: 100 Hz frames; a retention of 60 s and the default reset threshold of 10 s.
SETTINGS = dict(retention_seconds=60.0, window_seconds=10.0, baseline_repeat_k=3, alert_hysteresis_m=2)


@pytest.fixture
def clock_store(db_url: str) -> Iterator[Store]:
    s = open_store(db_url, settings=Settings(database_url=db_url, **SETTINGS))
    yield s
    s.close()


def without(rec: Recording, imu: str) -> Recording:
    """``rec`` with one IMU left out of every frame (it fell silent)."""
    keep = [k for k, n in enumerate(rec.imu_names) if n != imu]
    return Recording(
        rec.t,
        rec.joint_names,
        rec.q,
        tuple(rec.imu_names[k] for k in keep),
        rec.acc[:, keep],
        rec.gyro[:, keep],
    )


def test_clock_going_back_starts_an_epoch_that_reads_and_prunes_see(clock_store: Store) -> None:
    store, rng = clock_store, np.random.default_rng(3)
    feed(store, synth(rng, seconds=30), offset=1000.0)  # the old run: 1000.00 .. 1029.99 s
    info = store.robot("arm")
    assert info is not None and (info.epoch, info.epoch_start_t) == (0, None)
    assert info.last_frame_t == pytest.approx(1029.99)
    # A late batch within clock_reset_seconds (10 s) is the same clock: no new epoch.
    feed(store, synth(rng, seconds=1), offset=1021.0)
    assert store.robot("arm").epoch == 0
    assert store.robot("arm").last_frame_t == pytest.approx(1029.99)

    feed(store, synth(rng, seconds=12), offset=0.0)  # the robot restarted: 0.00 .. 11.99 s
    info = store.robot("arm")
    assert (info.epoch, info.epoch_start_t) == (1, 0.0)
    assert info.last_frame_t == pytest.approx(11.99)
    rec = store.read_window("arm", 10.0)
    assert rec is not None and rec.n_samples == 1000
    assert (rec.t[0], rec.t[-1]) == pytest.approx((2.0, 11.99))
    # Nothing of the new run is pruned, and the old epoch stays until the new one spans the retention.
    assert store.prune() == 0
    assert store.sample_count("arm") == 3000 + 100 + 1200
    old = store.read_between("arm", -np.inf, np.inf, epoch=0)
    assert old is not None and (old.t[0], old.t[-1]) == pytest.approx((1000.0, 1029.99))

    feed(store, synth(rng, seconds=60), offset=12.0)  # the new epoch reaches 71.99 s: 72 s long
    dropped = store.prune()
    assert store.read_between("arm", -np.inf, np.inf, epoch=0) is None
    kept = store.read_between("arm", -np.inf, np.inf)
    assert kept is not None and kept.t[-1] == pytest.approx(71.99)
    assert 10.0 <= kept.t[0] <= 12.0  # chunks ending before 71.99 - 60 s went, whole chunks only
    assert dropped == 3100 + (7200 - kept.n_samples)


def test_a_second_restart_drops_every_epoch_but_the_previous(clock_store: Store) -> None:
    store, rng = clock_store, np.random.default_rng(4)
    feed(store, synth(rng, seconds=5), offset=500.0)
    feed(store, synth(rng, seconds=5), offset=200.0)
    feed(store, synth(rng, seconds=5), offset=0.0)
    assert store.robot("arm").epoch == 2
    assert store.prune() == 500  # epoch 0 at once; epoch 1 stays until epoch 2 spans the retention
    assert store.read_between("arm", -np.inf, np.inf, epoch=1).n_samples == 500
    assert store.read_window("arm", 10.0).t[-1] == pytest.approx(4.99)


def test_imus_not_heard_since_the_restart_are_silent(clock_store: Store) -> None:
    store, rng = clock_store, np.random.default_rng(5)
    feed(store, synth(rng, seconds=12), offset=1000.0)
    rec = synth(rng, seconds=5)
    feed(store, without(rec, "c1"), offset=0.0)
    info = store.robot("arm")
    # c1 was heard at 1011.99 on the old clock: compared with the new clock's 4.99 it would look heard
    # in the future and never silent.
    assert info.epoch == 1 and info.silent_imus == ["c1"]


def test_worker_analyses_the_new_epoch_and_resolves_its_alert(clock_store: Store) -> None:
    store, rng = clock_store, np.random.default_rng(6)
    settings = Settings(database_url="sqlite://", **SETTINGS)
    end = feed(store, synth(rng, seconds=12), offset=1000.0)
    w = Worker(store, settings, estimator=Scripted(GOOD), clock=lambda: 5000.0)
    for _ in range(3):
        w.run_cycle()
    assert store.baseline("arm") is not None
    feed(store, synth(rng, seconds=12), offset=end, dead="b2")
    w.run_cycle()
    (tr,) = w.run_cycle()["arm"].transitions
    assert (tr.kind, tr.part, tr.state) == ("imu_dead", "imu:b2", "active")

    feed(store, synth(rng, seconds=12), offset=0.0)  # restart; b2 is alive again
    store.prune()
    first = w.run_cycle()["arm"]
    assert store.topology_history("arm", limit=1)[0].window_end_t == pytest.approx(11.99)
    assert first.health is not None and not first.health.dead_imus
    assert [t.state for t in first.transitions + w.run_cycle()["arm"].transitions] == ["resolved"]
    assert store.alerts("arm", active=True) == []


def test_api_accepts_a_restarted_clock_and_reports_the_epoch(clock_store: Store) -> None:
    def frames(t0: float) -> dict[str, object]:
        t = [t0 + 0.01 * k for k in range(3)]
        return {
            "t": t,
            "joint_names": ["j1"],
            "q": [[0.0]] * 3,
            "imu_names": ["imu0"],
            "acc": [[[0.0, 0.0, 9.81]]] * 3,
            "gyro": [[[0.0, 0.0, 0.0]]] * 3,
        }

    settings = Settings(database_url="sqlite://", max_time_jump_seconds=50.0, **SETTINGS)
    with TestClient(create_app(clock_store, settings=settings)) as c:
        assert c.post("/api/v1/robots/arm/frames", json=frames(90.0)).status_code == 201
        assert c.post("/api/v1/robots/arm/frames", json=frames(0.5)).status_code == 201
        robot = c.get("/api/v1/robots/arm").json()
        assert (robot["epoch"], robot["epoch_start_t"], robot["last_frame_t"]) == (1, 0.5, 0.52)
        # The jump bound now counts from the new epoch's newest frame.
        assert c.post("/api/v1/robots/arm/frames", json=frames(90.0)).status_code == 422
        assert c.post("/api/v1/robots/arm/frames", json=frames(40.0)).status_code == 201


def test_reset_threshold_comes_from_the_settings(db_url: str) -> None:
    store = open_store(db_url, settings=Settings(database_url=db_url, clock_reset_seconds=0.5))
    try:
        rng = np.random.default_rng(7)
        feed(store, synth(rng, seconds=2), offset=10.0)
        feed(store, synth(rng, seconds=1), offset=10.8)  # ends 0.21 s behind: overlap, same epoch
        assert store.robot("arm").epoch == 0
        feed(store, synth(rng, seconds=1), offset=9.0)  # ends 2 s behind: a restart
        assert store.robot("arm").epoch == 1
    finally:
        store.close()


def test_one_write_holding_both_clocks_splits_at_the_restart(clock_store: Store) -> None:
    store, rng = clock_store, np.random.default_rng(8)
    rec = synth(rng, seconds=2)

    def batch(offset: float) -> FrameBatch:
        return FrameBatch("arm", rec.t + offset, rec.joint_names, rec.q, rec.imu_names, rec.acc, rec.gyro)

    store.write_many([batch(100.0), batch(0.0), batch(2.0)])
    info = store.robot("arm")
    assert (info.epoch, info.epoch_start_t) == (1, 0.0) and info.last_frame_t == pytest.approx(3.99)
    assert store.read_window("arm", 60.0).n_samples == 400
    assert store.read_between("arm", -np.inf, np.inf, epoch=0).n_samples == 200
