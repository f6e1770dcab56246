"""The Kalibr imu.yaml export: noise densities as the recording has them, random walks near theirs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from bodyschema.discrepancy import analyze
from bodyschema.rigid_motion import reference_motion, smooth_random_motion
from sim2real.kalibr import kalibr_imu, write_kalibr_imu

RATE = 200.0
GYRO_DENSITY, ACC_DENSITY = 2e-3, 2e-2  # rad/s/√Hz, m/s²/√Hz
GYRO_WALK = 1e-3  # rad/s²/√Hz


def _report(seed: int = 4):
    rng = np.random.default_rng(seed)
    m = smooth_random_motion(60.0, RATE, rng)
    n = m["t"].size
    walk = np.cumsum(rng.normal(0.0, GYRO_WALK / np.sqrt(RATE), (n, 3)), axis=0)
    gyro = m["gyro"] + walk + rng.normal(0.0, GYRO_DENSITY * np.sqrt(RATE), (n, 3))
    acc = m["acc"] + rng.normal(0.0, ACC_DENSITY * np.sqrt(RATE), (n, 3))
    return analyze(reference_motion(m["t"], m["quat"], m["pos"], cutoff=10.0), gyro, acc)


def test_densities_rate_and_random_walks_as_kalibr_reads_them(tmp_path: Path) -> None:
    rep = _report()
    path = write_kalibr_imu(rep, tmp_path / "imu.yaml", rostopic="/imu2")
    imu = yaml.safe_load(path.read_text())
    want = kalibr_imu(rep, "/imu2")  # written to 6 significant digits
    assert imu.keys() == want.keys()
    assert all(v == want[k] if isinstance(v, str) else abs(v / want[k] - 1) < 1e-5 for k, v in imu.items())
    assert set(imu) == {
        "accelerometer_noise_density",
        "accelerometer_random_walk",
        "gyroscope_noise_density",
        "gyroscope_random_walk",
        "rostopic",
        "update_rate",
    }
    assert imu["rostopic"] == "/imu2" and imu["update_rate"] == RATE
    # the white noise as hidden (seed 4: within 1 %)
    assert abs(imu["gyroscope_noise_density"] / GYRO_DENSITY - 1) < 0.05
    assert abs(imu["accelerometer_noise_density"] / ACC_DENSITY - 1) < 0.05
    # the hidden random walk from 29 block differences per axis (seeds 4, 5, 6: 1.11, 0.67, 1.18 x)
    assert 0.5 * GYRO_WALK < imu["gyroscope_random_walk"] < 2 * GYRO_WALK
    # none hidden on the accelerometer: what is read there is the model's misfit (seed 4: 0.010)
    assert imu["accelerometer_random_walk"] < ACC_DENSITY
