"""Hide one effect at random in *measured* data (a BROAD trial): the analysis must find it on top.

BROAD: Laidig, Caruso, Cereatti, Seel, "BROAD—A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7), 2021, CC BY 4.0. The real IMU already differs from the motion capture (time
offset, lever arm, ...), so each test compares the analysis of the injected slice with a fit of the
same effects on the untouched slice: the difference must be what was injected.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodyschema.discrepancy import EFFECT_NAMES, analyze_recording, fit_params, prepare, reference_of
from bodyschema.discrepancy.inject import draw, inject
from service.broad import broad_data_dir, load_broad

TRIAL = broad_data_dir() / "02_undisturbed_slow_rotation_B.hdf5"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not TRIAL.exists(), reason="BROAD data not shared on this machine"),
]


@pytest.fixture(scope="module")
def trial():
    rec = load_broad(TRIAL).window(60.0, 100.0)  # 40 s of slow rotations
    prob = prepare(reference_of(rec), rec.gyro[:, 0], rec.acc[:, 0], rec.extra["ref_valid"])
    base = analyze_recording(rec)
    return rec, prob, base


def _vec(d: dict) -> np.ndarray:
    return np.ravel(next(iter(d.values())))


#: What the untouched 40 s slice of trial 02 names (measured once with the current analysis, the null
#: case below): a 3-5 ms time offset and a 5-12 mm lever arm (strong), a gyro bias and an accelerometer
#: scale (weak), besides the sensor noise.
TRIAL_EFFECTS = {"time_offset", "lever_arm", "gyro_bias", "acc_scale"}


def test_the_real_sensor_differs_by_a_time_offset_and_a_lever_arm(trial) -> None:
    _, _, base = trial
    assert base.names[:2] == ["time_offset", "lever_arm"]
    assert set(base.names) == TRIAL_EFFECTS | {"noise"}  # the null case: exactly the trial's own set
    assert 0.003 < base.params["time_offset"]["seconds"] < 0.005  # about one sample at 285.7 Hz
    assert 0.005 < np.linalg.norm(base.params["lever_arm"]["meters"]) < 0.012
    assert base.held_out["gain"] > 0.4
    assert "Laidig" in base.meta["attribution"]


@pytest.mark.parametrize("effect", EFFECT_NAMES)
def test_an_effect_hidden_in_measured_data_is_named_and_measured(effect: str, trial, rng) -> None:
    rec, prob0, base = trial
    true = draw(effect, rng)
    if effect == "acc_scale":
        # An equal gain on all three axes reads like a stronger gravity while the motion is slow
        # (the specific force is then mostly gravity): keep the drawn gains from sharing one sign.
        dev = np.asarray(true["matrix"]) - 1.0
        dev[0] = -np.sign(dev[1]) * abs(dev[0])
        true = {"matrix": (1.0 + dev).tolist()}
    if effect == "noise":
        # the sensor's own noise must not swamp the injected one: inject at least its level
        true = {
            "gyro_density": [float(rng.uniform(2e-3, 5e-3))] * 3,
            "acc_density": [float(rng.uniform(2e-2, 5e-2))] * 3,
        }
    g, a = inject(effect, true, rec.t, rec.gyro[:, 0], rec.acc[:, 0], rec.ref_quat, rng)
    rep = analyze_recording(replace(rec, gyro=g[:, None], acc=a[:, None]))
    assert effect in rep.names, f"injected {effect} {true}, named {rep.names}"
    # The exact set: the injected effect, the trial's strong effects, nothing the trial does not have.
    # The trial's weak effects (a gyro bias near 0.005 rad/s, a 1 % accelerometer scale) may drop out
    # when a larger effect is added: the selection then explains less of the residual with them (seen
    # for time_offset, acc_bias, lever_arm, noise and others at this trial's seeds).
    named = set(rep.names) - {"noise"}
    assert named - {effect} <= TRIAL_EFFECTS, f"named {sorted(named)} beyond the trial's own effects"
    assert {"time_offset", "lever_arm"} <= named | {effect}
    got = rep.params[effect]
    names = [n for n in rep.names if n != "noise"]
    before = fit_params(prob0, names, {}, prob0.index) if names else {}
    if effect == "time_offset":
        assert got["seconds"] - before["time_offset"]["seconds"] == pytest.approx(true["seconds"], abs=1e-3)
    elif effect in ("gyro_bias", "acc_bias", "lever_arm"):
        tol = {"gyro_bias": 2e-3, "acc_bias": 0.02, "lever_arm": 2e-3}[effect]
        assert np.allclose(_vec(got) - _vec(before[effect]), _vec(true), atol=tol)
    elif effect in ("gyro_scale", "acc_scale"):
        assert np.allclose(_vec(got) / _vec(before[effect]), _vec(true), atol=2e-3)
    elif effect == "mounting_rotation":
        rel = Rotation.from_rotvec(before[effect]["rotvec"]).inv() * Rotation.from_rotvec(got["rotvec"])
        err = rel.inv() * Rotation.from_rotvec(true["rotvec"])
        assert np.degrees(err.magnitude()) < 0.3
    elif effect == "gravity":
        assert np.allclose(_vec(got) - _vec(before[effect]) + [0, 0, -9.81], _vec(true), atol=0.03)
    elif effect == "noise":
        added = np.sqrt(np.array(got["std"]) ** 2 - np.array(base.params["noise"]["std"]) ** 2)
        want = np.concatenate([true["gyro_density"], true["acc_density"]]) * np.sqrt(got["rate_hz"])
        assert np.allclose(added, want, rtol=0.1)
