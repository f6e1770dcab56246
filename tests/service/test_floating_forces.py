"""The floating-base path on windows that carry foot forces: the stance-chain and stance-tilt checks.

The store keeps no foot forces yet (its chunks hold ``t``, ``q``, ``acc`` and ``gyro``), so here the
store's windows get the iCub log's own ``lf_force_z``/``rf_force_z`` back, sample for sample, on the
way to the worker: what the worker does once frames carry them. The robot is then floating by its
forces; the baseline (45 s: three 15 s windows) learns the contact threshold, a stance chain and the
tilt model; untouched windows raise nothing; a 2 deg turn of the IMU on its mount raises a pending
``imu_rotated`` alert through the tilt check (every threshold from ``stance_tilt``'s error model at its
default ``p_false``). The baseline, chain and tilt model included, survives a restart of the worker.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from bodyschema.faults import inject, parse_fault
from bodyschema.recording import Recording
from service.settings import Settings
from service.store import Store, open_store
from service.worker import Worker
from tests.service.floating_runs import ROBOT, feed, icub_log, no_fixed_fit, ticking

FORCES = ("lf_force_z", "rf_force_z")

pytestmark = pytest.mark.slow


def _with_forces(store: Store, rec: Recording) -> None:
    """``store.read_window`` hands out ``rec``'s foot forces at the window's stamps (the frames came
    from ``rec``, so every stamp is one of its own)."""
    read = store.read_window

    def read_window(robot: str, seconds: float, *args: object, **kwargs: object) -> Recording | None:
        w = read(robot, seconds, *args, **kwargs)  # type: ignore[arg-type]
        if w is None:
            return None
        idx = np.searchsorted(rec.t, w.t)
        assert np.array_equal(rec.t[idx], w.t)
        return dataclasses.replace(w, extra={k: rec.extra[k][idx] for k in FORCES})

    store.read_window = read_window  # type: ignore[method-assign]


def test_icub_with_foot_forces_runs_the_tilt_check_and_keeps_it_across_a_restart(tmp_path: Path) -> None:
    rec = icub_log()
    url = f"sqlite:///{tmp_path / 'forces.db'}"
    settings = Settings(database_url=url, window_seconds=15.0, baseline_repeat_k=3, alert_hysteresis_m=2)
    t0 = float(rec.t[0])
    imu = rec.imu_names[0]
    bad = inject(rec.window(t0 + 45, t0 + 90), parse_fault(f"imu_rotated:imu={imu},deg=2"))
    store = open_store(url)
    _with_forces(store, rec)
    worker = Worker(store, settings, estimator=no_fixed_fit, clock=ticking())  # type: ignore[arg-type]
    feed(store, rec.window(t0, t0 + 45))
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
    _with_forces(store, rec)
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
