"""The effect library, residual structure and the estimator API of bodyschema.discrepancy."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema import imu_effects as fx
from bodyschema.discrepancy import (
    EFFECTS,
    FITTED_EFFECTS,
    DiscrepancyAnalyzer,
    fit_params,
    predict,
    prepare,
    residual_structure,
)
from bodyschema.discrepancy.effects import pack, unpack
from bodyschema.discrepancy.fit import residual
from bodyschema.discrepancy.inject import draw, inject
from bodyschema.recording import Recording
from bodyschema.rigid_motion import reference_motion, smooth_random_motion


@pytest.fixture
def motion(rng: np.random.Generator) -> dict[str, np.ndarray]:
    return smooth_random_motion(20.0, 100.0, rng)


def test_null_parameters_predict_the_ideal_readings(motion) -> None:
    ref = reference_motion(motion["t"], motion["quat"], motion["pos"])
    nulls = {e: EFFECTS[e].to_params(np.asarray(EFFECTS[e].null)) for e in FITTED_EFFECTS}
    g0, a0 = predict(ref, {})
    g1, a1 = predict(ref, nulls)
    assert np.allclose(g0, g1) and np.allclose(a0, a1)
    assert np.allclose(a0, fx.specific_force(ref.R, ref.acc_world, ref.gravity))


def test_each_effect_predicts_what_the_shared_forward_model_injects(motion, rng) -> None:
    # predicting from the reference == injecting into the ideal readings (same imu_effects code)
    ref = reference_motion(motion["t"], motion["quat"], motion["pos"])
    g0, a0 = predict(ref, {})
    for e in FITTED_EFFECTS:
        p = draw(e, rng)
        g_inj, a_inj = inject(e, p, ref.t, g0, a0, motion["quat"], rng)
        g, a = predict(ref, {e: p})
        inner = slice(10, -10)
        assert np.allclose(g[inner], g_inj[inner], atol=1e-9), e
        assert np.allclose(a[inner], a_inj[inner], atol=1e-6), e


def test_pack_unpack_round_trip_and_bad_names(rng) -> None:
    names = list(FITTED_EFFECTS)
    x = rng.normal(size=pack({}, names).size)
    assert np.allclose(pack(unpack(x, names), names), x)
    with pytest.raises(ValueError, match="unknown effects"):
        predict(
            reference_motion(np.arange(5) * 0.1, np.tile([1.0, 0, 0, 0], (5, 1)), np.zeros((5, 3))),
            {"warp": {}},
        )
    with pytest.raises(ValueError, match="needs 3 values"):
        EFFECTS["gyro_bias"].from_params({"vector": [1.0, 2.0]})


def test_fitting_one_effect_holds_the_others_fixed(motion) -> None:
    ref = reference_motion(motion["t"], motion["quat"], motion["pos"], cutoff=10.0)
    g = motion["gyro"] + [0.02, 0.0, -0.01]
    prob = prepare(ref, g, motion["acc"])
    fixed = {"acc_bias": {"vector": [0.1, 0.0, 0.0]}}
    p = fit_params(prob, ["gyro_bias"], fixed, prob.index)
    assert np.allclose(p["gyro_bias"]["vector"], [0.02, 0.0, -0.01], atol=1e-4)
    assert p["acc_bias"] == fixed["acc_bias"]


def test_residual_structure_points_at_the_cause(motion) -> None:
    ref = reference_motion(motion["t"], motion["quat"], motion["pos"], cutoff=10.0)
    g = fx.affine(motion["gyro"], matrix=[1.03, 1.0, 1.0])  # x gain
    a = motion["acc"] + [0.0, 0.0, 0.3]  # z bias
    prob = prepare(ref, g, a)
    r, pred = residual(prob, {})
    st = residual_structure(prob.ref, r, pred, prob.index, prob.rate)
    assert st["gyro"]["r2"]["reading"][0] > 0.99  # gyro x residual follows the gyro x reading
    assert st["acc"]["r2"]["constant"][2] > 0.99  # acc z residual is a constant
    assert st["acc"]["mean"][2] == pytest.approx(0.3, abs=1e-3)


def test_estimator_api(motion) -> None:
    g = motion["gyro"] + [0.0, 0.0, 0.05]
    rec = Recording(
        t=motion["t"],
        joint_names=(),
        q=None,
        imu_names=("imu0",),
        acc=motion["acc"][:, None],
        gyro=g[:, None],
        ref_quat=motion["quat"],
        ref_pos=motion["pos"],
    )
    est = DiscrepancyAnalyzer(n_blocks=6)
    assert est.fit(rec) is est
    assert est.causes_ == ["gyro_bias"]
    gyro, _ = est.predict(rec)
    assert np.allclose(gyro[50:-50], g[50:-50], atol=5e-3)
    assert est.report_.to_json()["causes"][0]["effect"] == "gyro_bias"
