"""The floating-base path on windows that carry foot forces: the stance-chain and stance-tilt checks.

The iCub log's frames carry its ``lf_force_z``/``rf_force_z`` as channels, as the replay source sends
them; the store keeps them with the chunks and hands them back with each window. The robot is floating
by its forces; the baseline (45 s: three 15 s windows) learns the contact threshold, a stance chain and the
tilt model; untouched windows raise nothing; a 2 deg turn of the IMU on its mount raises a pending
``imu_rotated`` alert through the tilt check (every threshold from ``stance_tilt``'s error model at its
default ``p_false``). The baseline, chain and tilt model included, survives a restart of the worker.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bodyschema.faults import inject, parse_fault
from service.settings import Settings
from service.store import open_store
from service.worker import Worker
from tests.service.floating_runs import ROBOT, feed, icub_log, no_fixed_fit, ticking

FORCES = ("lf_force_z", "rf_force_z")

pytestmark = pytest.mark.slow


def test_icub_with_foot_forces_runs_the_tilt_check_and_keeps_it_across_a_restart(tmp_path: Path) -> None:
    rec = icub_log()
    url = f"sqlite:///{tmp_path / 'forces.db'}"
    settings = Settings(database_url=url, window_seconds=15.0, baseline_repeat_k=3, alert_hysteresis_m=2)
    t0 = float(rec.t[0])
    imu = rec.imu_names[0]
    bad = inject(rec.window(t0 + 45, t0 + 90), parse_fault(f"imu_rotated:imu={imu},deg=2"))
    store = open_store(url)
    worker = Worker(store, settings, estimator=no_fixed_fit, clock=ticking())  # type: ignore[arg-type]
    feed(store, rec.window(t0, t0 + 45))
    w = store.read_window(ROBOT, 15.0)  # the forces come back from the store, sample for sample
    assert w is not None and set(FORCES) <= set(w.extra)  # with the other time-long extras (wrenches)
    idx = np.searchsorted(rec.t, w.t)
    assert all(np.array_equal(w.extra[k], rec.extra[k][idx]) for k in FORCES)
    res = worker.run_cycle()[ROBOT]
    assert res.baseline_set
    fr = worker.floating.robots[ROBOT]
    assert fr.rule == "the recording carries foot forces (lf_force_z, rf_force_z)"
    base = fr.baseline
    assert base is not None and base.force_threshold is not None and base.force_threshold.shape == (2,)
    assert [c.phase for c in base.chains] == ["lf_force_z down", "rf_force_z down"] and base.tilt is not None
    waits = store.waiting(ROBOT)[ROBOT]["waits"]
    assert len(waits) == 1 and "undetermined" not in waits[0]["what"]  # every check runs

    feed(store, rec.window(t0 + 45, t0 + 60))  # untouched: judged, nothing found
    res = worker.run_cycle()[ROBOT]
    assert res.diff is not None and res.diff.findings == ()
    store.close()

    store = open_store(url)  # a restart: the baseline with its chain and tilt model read back
    again = Worker(store, settings, estimator=no_fixed_fit, clock=ticking(3000.0))  # type: ignore[arg-type]
    try:
        feed(store, bad.window(t0 + 60, t0 + 75))  # the forces are the log's: only the IMU turned
        res = again.run_cycle()[ROBOT]
        assert not res.baseline_set and res.diff is not None
        assert [(f.kind, f.part) for f in res.diff.findings] == [("imu_rotated", f"imu:{imu}")]
        assert "stance feet's gravity off the IMU's" in res.diff.findings[0].detail
        assert [(t.kind, t.state) for t in res.pending] == [("imu_rotated", "pending")]
        kept = again.floating.robots[ROBOT].baseline
        assert kept is not None and kept.tilt is not None and base.tilt is not None
        assert np.array_equal(kept.tilt.block_means, base.tilt.block_means)
        assert np.array_equal(kept.chains[0].axes, base.chains[0].axes)
        assert [(a.kind, a.part, a.state) for a in store.alerts(ROBOT)] == [
            ("imu_rotated", f"imu:{imu}", "pending")
        ]
        assert again.metrics.cycle_errors._value.get() == 0
    finally:
        store.close()
