"""The worker on a floating-base robot: the iCub walking log's frames in a real store.

The frames here carry no foot forces (a source without them), so the robot is taken as floating-base
because dropping the velocity jumps at its contacts leaves too few samples for a fixed-base fit
(:mod:`service.monitor.floating`); with them, see ``test_floating_forces``.
The baseline is learned on ``baseline_repeat_k`` windows of frames; untouched windows raise nothing;
a frozen knee encoder raises a pending ``encoder_fault`` alert on the knee. The baseline is kept in
the store: a worker restarted on the same SQLite file judges on without learning it again, and the
API says the robot has a (floating) baseline.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bodyschema.faults import inject, parse_fault
from bodyschema.floating_health import FloatingBaseline
from service.api import create_app
from service.frames import FrameBatch
from service.settings import Settings
from service.store import Store, open_store
from service.worker import Worker
from tests.robot_data import MAPS, ROBOTS
from tests.service.floating_runs import ROBOT, feed, icub_log, no_fixed_fit, ticking

pytestmark = pytest.mark.slow


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = open_store(f"sqlite:///{tmp_path / 'f.db'}")
    yield s
    s.close()


def test_icub_baseline_quiet_windows_and_a_frozen_knee(store: Store) -> None:
    rec = icub_log()
    settings = Settings(
        database_url="sqlite://",
        window_seconds=10.0,
        baseline_repeat_k=3,
        alert_hysteresis_m=2,
        worker_interval_seconds=0.05,
    )
    worker = Worker(store, settings, estimator=no_fixed_fit, clock=ticking())  # type: ignore[arg-type]
    t0 = float(rec.t[0])

    feed(store, rec.window(t0, t0 + 30), forces=False)
    res = worker.run_cycle()[ROBOT]
    assert res.baseline_set and res.skipped == ""
    fr = worker.floating.robots[ROBOT]
    assert fr.rule.startswith("one IMU, and velocity jumps at contacts")
    assert fr.baseline is not None and fr.baseline.force_threshold is None  # no foot forces sent
    waits = store.waiting(ROBOT)[ROBOT]["waits"]
    assert len(waits) == 1 and "judged by the floating-base checks" in waits[0]["what"]
    assert "encoder offsets and a turned IMU undetermined" in waits[0]["what"]

    for s in (30, 40, 50):  # untouched windows: judged, nothing found, no alert
        feed(store, rec.window(t0 + s, t0 + s + 10), forces=False)
        res = worker.run_cycle()[ROBOT]
        assert res.skipped == "" and res.diff is not None, s
        assert res.diff.findings == (), s
    assert store.alerts(ROBOT) == []

    bad = inject(rec.window(t0 + 60, t0 + 80), parse_fault("encoder_frozen:joint=l_knee"))
    feed(store, bad.window(t0 + 60, t0 + 70), forces=False)
    res = worker.run_cycle()[ROBOT]
    assert res.diff is not None
    assert [(f.kind, f.part) for f in res.diff.findings] == [("encoder_fault", "joint:l_knee")]
    assert [(t.kind, t.part, t.state) for t in res.pending] == [("encoder_fault", "joint:l_knee", "pending")]
    alerts = store.alerts(ROBOT)
    assert [(a.kind, a.part, a.state) for a in alerts] == [("encoder_fault", "joint:l_knee", "pending")]
    assert worker.metrics.cycle_errors._value.get() == 0


def test_go1_is_floating_once_its_fixed_base_fits_keep_a_turning_imu_on_no_joint(store: Store) -> None:
    """The Go1's point feet strike softly: its windows keep their samples, the fixed-base fit runs and
    hangs the trunk IMU on no joint; after ``baseline_repeat_k`` such cycles it is floating-base."""
    from sim2real.robot_logs import import_log

    path = ROBOTS / "go1-trot" / "go1.csv"
    if not path.is_file():
        pytest.skip(f"robot log missing: {path}")
    rec = import_log(path, MAPS / "go1-trot.toml", "csv")[0]
    settings = Settings(database_url="sqlite://", window_seconds=10.0, baseline_repeat_k=3)
    worker = Worker(store, settings, clock=ticking())
    t0, span = float(rec.t[0]), float(rec.t[-1] - rec.t[0]) + 1 / rec.sample_rate
    results = []

    def feed_cycle(c: int) -> None:  # 10 s per cycle, the 25 s log looped on in device time
        for s in range(10 * c, 10 * c + 10):
            loop, at = divmod(float(s), span)
            part = rec.window(t0 + at, t0 + at + 1.0)
            off = loop * span
            store.write(
                FrameBatch("go1", part.t + off, rec.joint_names, part.q, rec.imu_names, part.acc, part.gyro)
            )

    for c in range(6):
        feed_cycle(c)
        results.append(worker.run_cycle()["go1"])
    assert [r.baseline_set for r in results] == [False, False, False, True, False, False]
    assert worker.floating.robots["go1"].rule.startswith("the fixed-base fit of 3 cycles in a row")
    assert [r.diff.findings if r.diff else None for r in results[4:]] == [(), ()]
    assert store.alerts("go1") == []
    assert worker.metrics.cycle_errors._value.get() == 0

    # restarted on the same store: the kept baseline and its rule judge the first window, without the
    # fixed-base fits that found the rule
    again = Worker(store, settings, estimator=no_fixed_fit, clock=ticking(5000.0))  # type: ignore[arg-type]
    feed_cycle(6)
    res = again.run_cycle()["go1"]
    assert not res.baseline_set and res.diff is not None and res.diff.findings == ()
    assert again.floating.robots["go1"].rule == worker.floating.robots["go1"].rule
    assert again.metrics.cycle_errors._value.get() == 0


def _same(a: FloatingBaseline, b: FloatingBaseline) -> bool:
    """Every field of the two baselines equal, arrays bit for bit."""
    arrays = ("quantum", "moving", "max_jerk", "still_run_s", "imu_repeat", "imu_run")
    return (
        a.joint_names == b.joint_names
        and a.imu_names == b.imu_names
        and all(np.array_equal(getattr(a, f), getattr(b, f)) for f in arrays)
        and (a.force_threshold is None) == (b.force_threshold is None)
        and len(a.chains) == len(b.chains)
        and (a.tilt is None) == (b.tilt is None)
    )


def test_icub_baseline_is_kept_in_the_store_across_a_restart(tmp_path: Path) -> None:
    """Learned once, read back by a restarted worker on the same SQLite file: its first cycle judges
    (no baseline learned again, none stored again), a frozen knee still raises its alert, and the
    API reports a floating baseline."""
    rec = icub_log()
    url = f"sqlite:///{tmp_path / 'restart.db'}"
    settings = Settings(
        database_url=url,
        window_seconds=10.0,
        baseline_repeat_k=3,
        alert_hysteresis_m=2,
        api_cache_seconds=0.0,
    )
    t0 = float(rec.t[0])
    first = open_store(url)
    worker = Worker(first, settings, estimator=no_fixed_fit, clock=ticking())  # type: ignore[arg-type]
    feed(first, rec.window(t0, t0 + 30), forces=False)
    assert worker.run_cycle()[ROBOT].baseline_set
    learned = worker.floating.robots[ROBOT]
    assert learned.baseline is not None
    kept = first.floating_baseline(ROBOT)
    assert kept is not None and kept.rule == learned.rule and kept.window_end_t == learned.baseline_end
    first.close()

    store = open_store(url)
    try:
        again = Worker(store, settings, estimator=no_fixed_fit, clock=ticking(2000.0))  # type: ignore[arg-type]
        feed(store, rec.window(t0 + 30, t0 + 40), forces=False)
        res = again.run_cycle()[ROBOT]
        assert not res.baseline_set and res.skipped == "" and res.diff is not None
        assert res.diff.findings == ()
        fr = again.floating.robots[ROBOT]
        assert fr.baseline is not None and _same(fr.baseline, learned.baseline)
        assert (fr.rule, fr.baseline_end, fr.baseline_at) == (
            learned.rule,
            learned.baseline_end,
            kept.wall_time,
        )
        assert store.floating_baseline(ROBOT) == kept  # judged on: nothing learned or stored again

        bad = inject(rec.window(t0 + 40, t0 + 60), parse_fault("encoder_frozen:joint=l_knee"))
        feed(store, bad.window(t0 + 40, t0 + 50), forces=False)
        res = again.run_cycle()[ROBOT]
        assert [(t.kind, t.part, t.state) for t in res.pending] == [
            ("encoder_fault", "joint:l_knee", "pending")
        ]
        assert again.metrics.cycle_errors._value.get() == 0

        c = TestClient(create_app(store, settings=settings))
        body = c.get(f"/api/v1/robots/{ROBOT}").json()
        assert body["has_baseline"] is True
        st = body["status"]
        assert (st["has_baseline"], st["baseline_kind"], st["baseline_source"]) == (True, "floating", "auto")
        assert st["reasons"][0].startswith("floating-base baseline learned")
        assert not any(r.startswith(("no baseline yet", "nothing learned yet")) for r in st["reasons"])
        assert c.get(f"/api/v1/robots/{ROBOT}/status").json() == st
        listed = {r["name"]: r for r in c.get("/api/v1/robots").json()}
        assert (
            listed[ROBOT]["has_baseline"] is True and listed[ROBOT]["status"]["baseline_kind"] == "floating"
        )
    finally:
        store.close()
