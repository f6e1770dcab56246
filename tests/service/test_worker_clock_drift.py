"""Two clocks drifted apart past the lag search's reach: the worker follows the lag.

A quadruped (its gait repeats, so a lag search that misses the true peak finds a wrong one inside its
±100 ms range) runs in the farm on the ``robot`` sensing preset (IMU clock 30 ppm fast against the
encoders') with its IMU stamps 93 ms late from the start, as two free-running clocks 30 ppm apart
are after 52 minutes: the lag behind the encoders (the skew and the gyro filter's 4.8 ms) passes
100 ms after about 10 worker cycles, a few after the baseline stands. Asserted: once the baseline stands no
cycle shows any finding, through 40 cycles, and the lag reported at the end is the true one (skew,
filter delay and drift to the middle of the window), past the search's reach.
"""

from __future__ import annotations

import dataclasses
import logging

import pytest

from bodyschema.timing import DLPF_GYRO
from service.ingest.replay import recording_batch
from service.settings import Settings
from service.store import open_store
from service.worker import Worker
from simulators.farm import Farm
from simulators.sensing import PRESETS

pytestmark = pytest.mark.slow

SKEW = 0.093
#: Worker cycles, each on 5 s more of device time (after 5 chunks of 5 s before the first).
CYCLES = 40


def test_lag_past_the_search_range_raises_nothing() -> None:
    logging.getLogger("service.worker").setLevel(logging.ERROR)
    sensing = dataclasses.replace(PRESETS["robot"], skew=SKEW)
    farm = Farm({"r": "quadruped"}, seed=0, sensing=sensing)
    # the fast screen's lag is what is tested; the geometry's estimates (which take its timing) are off
    settings = Settings(database_url="sqlite://", network_interval_cycles=0, kinematics_interval_cycles=0)
    store = open_store("sqlite://", settings=settings)
    worker = Worker(store, settings)
    findings, lags = [], []
    for _ in range(5):
        for name, rec in farm.advance(5.0).items():
            store.write(recording_batch(name, rec))
    for _ in range(CYCLES):
        for name, rec in farm.advance(5.0).items():
            store.write(recording_batch(name, rec))
        res = worker.run_cycle()["r"]
        if store.baseline("r") is not None and res.diff is not None:
            findings.append([(f.kind, f.part) for f in res.diff.findings])
        lags.append(res.topology.timing["lag_ms"] if res.topology is not None else None)
    store.close()
    assert len(findings) > CYCLES - 20 and all(f == [] for f in findings), list(enumerate(findings))
    t_mid = (5 + CYCLES) * 5.0 - 15.0
    delay = DLPF_GYRO[sensing.dlpf_cfg][1]
    assert lags[-1] == pytest.approx(1e3 * (SKEW + delay + 1e-6 * sensing.drift_ppm * t_mid), abs=2.0), lags
    assert lags[-1] > 100.0 and min(lags) > 85.0, lags
