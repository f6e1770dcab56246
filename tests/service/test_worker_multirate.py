"""The worker on multi-rate windows from the simulated farm under the ``robot`` sensing preset, with
the real fast estimator: a baseline is learned, nominal cycles raise nothing, and a moved IMU raises
``imu_moved`` first (never a passing ``imu_detached`` while the window straddles the move)."""

from __future__ import annotations

import pytest

from service.ingest.replay import recording_batch
from service.settings import Settings
from service.store import Store, open_store
from service.worker import Worker
from simulators.farm import Farm


def _step(farm: Farm, store: Store, seconds: float) -> None:
    for _ in range(round(seconds * 10)):
        for name, rec in farm.advance(0.1).items():
            store.write(recording_batch(name, rec))


@pytest.mark.slow
def test_moved_imu_on_robot_sensing_raises_imu_moved_first(db_url: str) -> None:
    farm = Farm({"r": "paper-3"}, seed=0, sensing="robot")
    settings = Settings(database_url=db_url, window_seconds=10.0, baseline_repeat_k=3, alert_hysteresis_m=2)
    with open_store(db_url) as store:
        w = Worker(store, settings)
        _step(farm, store, 10.0)
        window = store.read_window("r", 10.0)
        assert window is not None and window.is_multirate
        for _ in range(3):
            _step(farm, store, 4.0)
            w.run_cycle()
        assert store.baseline("r") is not None
        for _ in range(2):  # nominal: nothing found, nothing raised
            _step(farm, store, 4.0)
            res = w.run_cycle()["r"]
            assert res.diff is not None and res.diff.findings == ()
        assert store.alerts("r") == []
        (truth,) = farm.apply_damage("r", "imu_moved", imu="imu35").findings
        raised = []
        for _ in range(5):
            _step(farm, store, 4.0)
            raised += [(tr.kind, tr.part) for tr in w.run_cycle()["r"].transitions if tr.state == "active"]
        assert raised and raised[0] == ("imu_moved", "imu:imu35")
        assert [(a.kind, a.part) for a in store.alerts("r")] == [("imu_moved", "imu:imu35")]
        assert store.alerts("r")[0].finding["to"] == truth.to


def test_stated_filter_delay_is_taken_out_of_the_reported_skew(db_url: str) -> None:
    """The lag the estimator finds is the clock skew plus the IMU filter's group delay; the service
    reports the skew alone when the delay is stated (``imu_filter_delay_ms``), and the lag otherwise.
    The robot preset: 8 ms skew, DLPF_CFG 3 (4.8 ms), 30 ppm drift (simulators/sensing.py); the lag
    is found within its stated 2 ms (bodyschema.fast)."""
    from service.daemon import _with_farm_filter_delay
    from service.ingest.farm import FarmSource

    farm = Farm({"r": "paper-3"}, seed=0, sensing="robot")
    with open_store(db_url) as store:
        _step(farm, store, 10.0)
        timings = []
        for delay in (None, 4.8):
            settings = Settings(database_url=db_url, window_seconds=10.0, imu_filter_delay_ms=delay)
            topo = Worker(store, settings).run_cycle()["r"].topology
            assert topo is not None
            timings.append(topo.timing)
    unstated, stated = timings
    assert unstated["lag_ms"] == stated["lag_ms"] == pytest.approx(8.0 + 4.8, abs=2.0)
    assert unstated["skew_ms"] == unstated["lag_ms"]
    assert stated["skew_ms"] == pytest.approx(stated["lag_ms"] - 4.8, abs=1e-9)
    # the farm's IMUs are known parts: unstated, the service takes the delay of the farm's filter
    base = Settings(database_url=db_url)
    robot, ideal = FarmSource(farm), FarmSource(Farm({"r": "paper-3"}, sensing="ideal"))
    assert _with_farm_filter_delay(base, [robot]).imu_filter_delay_ms == pytest.approx(4.8)
    assert _with_farm_filter_delay(base, [ideal]).imu_filter_delay_ms == 0.0
    assert _with_farm_filter_delay(base, []).imu_filter_delay_ms is None
    assert _with_farm_filter_delay(base, [robot, ideal]).imu_filter_delay_ms is None
    stated = base.model_copy(update={"imu_filter_delay_ms": 1.0})
    assert _with_farm_filter_delay(stated, [robot]).imu_filter_delay_ms == 1.0
