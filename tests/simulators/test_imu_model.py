"""The IMU error model: presets measured back from simulated data, physical checks of the effects,
JSON round trips, streaming."""

from __future__ import annotations

import json
import math

import mujoco
import numpy as np
import pytest

from simulators.builder import build_spec
from simulators.catalog import describe
from simulators.imu_model import (
    PRESETS,
    ImuModel,
    ImuParams,
    ImuStream,
    apply,
    load_imu_model,
    resolve_imu_model,
    save_imu_model,
)
from simulators.robot import Robot
from simulators.simulation import Simulation

DEG = math.pi / 180


def _pair(name: str, excitation: str, seconds: float, seed: int):
    """The same run twice: ideal IMUs and MPU-6050 IMUs (same motion: independent random streams)."""
    ideal = Simulation(name, seed=seed, imu_model="ideal", excitation=excitation)
    real = Simulation(name, seed=seed, imu_model="mpu6050", excitation=excitation)
    n = int(seconds * 100)
    return ideal.advance(n), real.advance(n), real.params


def test_mpu6050_noise_and_gyro_bias_from_a_static_recording(seed: int) -> None:
    ideal, rec, p = _pair("paper-1", "hold", 20.0, seed)
    assert np.allclose(ideal.q, rec.q)
    assert np.abs(ideal.gyro).max() < 1e-6  # it really is static
    # zero-rate offset: the mean of a static gyro
    gb = rec.gyro.mean(axis=0)
    assert np.linalg.norm(gb - p.gyro_bias) <= 0.1 * np.linalg.norm(p.gyro_bias)
    assert np.abs(p.gyro_bias).max() <= 20 * DEG and np.abs(p.gyro_bias).max() > 5 * DEG
    # white noise: std of static readings vs density * sqrt(rate)
    g_std, a_std = p.noise_std(100.0)
    assert g_std == pytest.approx(0.005 * DEG * 10)
    assert a_std == pytest.approx(400e-6 * 9.80665 * 10)
    measured_g = rec.gyro.std(axis=0).mean(axis=0)
    measured_a = (rec.acc - ideal.acc @ np.eye(3)).std(axis=0).mean(axis=0)
    assert np.allclose(measured_g, g_std, rtol=0.1)
    assert np.allclose(measured_a, a_std, rtol=0.1)


def _fit(ideal: np.ndarray, measured: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, float]:
    X = np.c_[ideal[:, k], np.ones(len(ideal))]
    sol, *_ = np.linalg.lstsq(X, measured[:, k], rcond=None)
    return sol[:3].T, sol[3], float(np.linalg.cond(X))


def _within_10_percent(pairs: list[tuple[np.ndarray, np.ndarray]]) -> None:
    err = np.linalg.norm([m - c for m, c in pairs])
    size = np.linalg.norm([c for _, c in pairs])
    assert err <= 0.1 * size, (err, size)


def test_mpu6050_scale_cross_axis_and_acc_bias_measured_back(seed: int) -> None:
    eye = np.eye(3)
    # gyro sensitivity: a known rotation (the ideal run of the same motion) regressed on the reading
    ideal, rec, p = _pair("paper-1", "observable", 20.0, seed)
    pairs = []
    for k in range(rec.n_imus):
        M, _, cond = _fit(ideal.gyro, rec.gyro, k)
        if cond < 50:  # IMUs that turned about all three of their axes
            pairs.append((M - eye, p.gyro_matrix[k] - eye))
    assert len(pairs) >= 24
    _within_10_percent(pairs)
    # accelerometer sensitivity and zero-g offset: static poses in many orientations
    ideal, rec, p = _pair("paper-1", "poses", 30.0, seed)
    scale, bias = [], []
    for k in range(rec.n_imus):
        M, b, cond = _fit(ideal.acc, rec.acc, k)
        if cond < 50:
            scale.append((M - eye, p.acc_matrix[k] - eye))
            bias.append((b, p.acc_bias[k]))
    assert len(scale) >= 24
    _within_10_percent(scale)
    _within_10_percent(bias)
    # the draws respect the datasheet ranges
    diag = np.diagonal(p.gyro_matrix, axis1=1, axis2=2)
    assert np.all(np.abs(diag - 1) <= 0.03)
    off = p.gyro_matrix - diag[:, :, None] * np.eye(3)
    assert np.all(np.abs(off) <= 0.02) and np.abs(off).max() > 0.005
    assert np.all(np.abs(p.acc_bias) <= [0.05 * 9.80665, 0.05 * 9.80665, 0.08 * 9.80665])


def _robot_with_twin_site(offset_in_sensor: np.ndarray, rotvec: np.ndarray) -> Robot:
    """paper-1 with an extra site 'twin' next to imu13: displaced by ``offset`` (sensor frame) and
    rotated by ``rotvec`` relative to it, with its own sensors."""
    spec = build_spec(describe("paper-1"))
    site = spec.site("imu13")
    q = np.array(site.quat)
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, q)
    pos = np.array(site.pos) + R.reshape(3, 3) @ offset_in_sensor
    dq = np.zeros(4)
    mujoco.mju_axisAngle2Quat(dq, rotvec / max(np.linalg.norm(rotvec), 1e-12), np.linalg.norm(rotvec))
    q2 = np.zeros(4)
    mujoco.mju_mulQuat(q2, q, dq)
    body = site.parent
    body.add_site(name="imu60", pos=pos.tolist(), quat=q2.tolist())
    for kind, st in (("acc", mujoco.mjtSensor.mjSENS_ACCELEROMETER), ("gyro", mujoco.mjtSensor.mjSENS_GYRO)):
        spec.add_sensor(name=f"imu60:{kind}", type=st, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu60")
    return Robot(spec, name="twin")


@pytest.mark.parametrize("effect", ["lever_arm", "mounting_rotation"])
def test_lever_arm_and_mounting_rotation_match_a_physically_moved_sensor(
    effect: str, rng: np.random.Generator
) -> None:
    r = rng.uniform(-0.05, 0.05, 3) if effect == "lever_arm" else np.zeros(3)
    rv = rng.uniform(-0.3, 0.3, 3) if effect == "mounting_rotation" else np.zeros(3)
    robot = _robot_with_twin_site(r, rv)
    from simulators.excitation import make_excitation

    exc = make_excitation("random-torque").bind(robot, rng)
    s = robot.sample(exc.ctrl(robot, np.arange(100) / robot.rate), poses=True)
    src, twin = robot.imu_names.index("imu13"), robot.imu_names.index("imu60")
    key = "meters" if effect == "lever_arm" else "rotvec"
    model = ImuModel("one", ((effect, {key: (r if effect == "lever_arm" else rv).tolist()}),))
    p = model.instantiate(("imu13",), rng)
    acc, gyro = apply(
        p,
        s.t,
        s.acc[:, [src]],
        s.gyro[:, [src]],
        rate=robot.rate,
        rng=rng,
        gyro_dot=s.gyro_dot[:, [src]],
        R=s.R[:, [src]],
    )
    scale = np.abs(s.acc[:, twin]).max()
    assert np.abs(acc[:, 0] - s.acc[:, twin]).max() <= 1e-6 * scale
    assert np.abs(gyro[:, 0] - s.gyro[:, twin]).max() <= 1e-6 * max(np.abs(s.gyro[:, twin]).max(), 1.0)
    assert np.abs(s.acc[:, twin] - s.acc[:, src]).max() > 1e-3  # the effect is not negligible


def test_gravity_off_and_time_offset(seed: int) -> None:
    model = ImuModel("g", (("gravity", {"vector": [0, 0, 0]}), ("time_offset", {"seconds": 0.02})))
    ideal = Simulation("ur5e", seed=seed, imu_model="ideal", excitation="hold").advance(50)
    rec = Simulation("ur5e", seed=seed, imu_model=model, excitation="hold").advance(50)
    assert np.abs(ideal.acc).max() > 9.0
    assert np.abs(rec.acc).max() < 1e-5  # at rest without gravity an accelerometer reads nothing
    moving = Simulation("ur5e", seed=seed, imu_model=ImuModel("t", (("time_offset", {"seconds": 0.02}),)))
    ref = Simulation("ur5e", seed=seed, imu_model="ideal")
    a, b = moving.advance(100), ref.advance(100)
    assert np.allclose(a.gyro[2:], b.gyro[:-2], atol=1e-9)  # 20 ms = 2 samples late


def test_json_round_trip_and_drawn_parameters_reproduce(tmp_path, rng: np.random.Generator) -> None:
    names = tuple(f"imu{i}" for i in range(4))
    p = PRESETS["mpu6050"].instantiate(names, rng)
    fixed = p.to_model("drawn")
    path = tmp_path / "m.json"
    save_imu_model(fixed, path)
    again = load_imu_model(path).instantiate(names, np.random.default_rng(0))
    for f in ("gyro_matrix", "acc_matrix", "gyro_bias", "acc_bias", "gyro_noise", "acc_noise"):
        assert np.allclose(getattr(again, f), getattr(p, f)), f
    assert again.gyro_lsb == p.gyro_lsb and again.acc_range == p.acc_range
    data = json.loads(path.read_text())
    assert {e["effect"] for e in data["effects"]} >= {"gyro_bias", "acc_bias", "gyro_scale", "noise"}
    assert resolve_imu_model(str(path)).name == "drawn"


def test_fitted_model_in_discrepancy_style_applies(rng: np.random.Generator) -> None:
    model = ImuModel.from_json(
        {
            "name": "fitted",
            "effects": [
                {"effect": "gyro_bias", "params": {"vector": [0.01, -0.02, 0.0]}},
                {"effect": "acc_scale", "params": {"matrix": [1.02, 0.98, 1.0]}},
                {"effect": "sample_rate", "params": {"hz": 200}},
            ],
        }
    )
    assert model.rate == 200.0
    p = model.instantiate(("imu0",), rng)
    acc, gyro = apply(p, np.arange(2) * 0.005, np.ones((2, 1, 3)), np.zeros((2, 1, 3)), rate=200.0, rng=rng)
    assert np.allclose(gyro[0, 0], [0.01, -0.02, 0.0]) and np.allclose(acc[0, 0], [1.02, 0.98, 1.0])


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ({"effects": [{"effect": "warp_drive", "params": {}}]}, "unknown IMU effect 'warp_drive'"),
        ({"effects": [{"effect": "gyro_bias", "params": {"vector": [1, 2]}}]}, "scalar or 3-vector"),
        (
            {"effects": [{"effect": "gyro_bias", "params": {"per_imu": {"nope": {"vector": [0, 0, 0]}}}}]},
            r"unknown IMUs \['nope'\]",
        ),
        ({"format": "other/2", "effects": []}, "unsupported IMU model format 'other/2'"),
        ({"effects": [{"params": {}}]}, "malformed IMU model JSON"),
    ],
)
def test_malformed_models_are_rejected(bad: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ImuModel.from_json(bad).instantiate(("imu0",), np.random.default_rng(0))


def test_stream_in_chunks_equals_one_batch(rng: np.random.Generator) -> None:
    names = ("imu0", "imu1")
    offsets = {"imu0": {"seconds": 0.013}, "imu1": {"seconds": 0.031}}
    model = ImuModel(
        "s",
        (
            ("time_offset", {"per_imu": offsets}),
            ("gyro_bias", {"uniform": 0.1}),
            ("noise", {"gyro_density": 0.001, "acc_density": 0.01}),
        ),
    )
    p = model.instantiate(names, rng)
    t = np.arange(300) / 100.0
    acc = np.sin(t)[:, None, None] * rng.normal(size=(1, 2, 3))
    gyro = np.cos(3 * t)[:, None, None] * rng.normal(size=(1, 2, 3))
    whole = ImuStream(p, 100.0, np.array([0, 0, -9.81])).process(t, acc, gyro, np.random.default_rng(5))
    stream = ImuStream(p, 100.0, np.array([0, 0, -9.81]))
    noise = np.random.default_rng(5)
    parts = [stream.process(t[i:j], acc[i:j], gyro[i:j], noise) for i, j in ((0, 7), (7, 150), (150, 300))]
    assert np.allclose(np.concatenate([a for a, _ in parts]), whole[0], atol=1e-12)
    assert np.allclose(np.concatenate([g for _, g in parts]), whole[1], atol=1e-12)


def test_identity_params_change_nothing(rng: np.random.Generator) -> None:
    p = ImuParams.identity(("imu0",))
    x = rng.normal(size=(5, 1, 3))
    a, g = apply(p, np.arange(5) * 0.01, x, x, rate=100.0, rng=rng)
    assert np.array_equal(a, x) and np.array_equal(g, x)


def test_sample_rate_effect_sets_the_recording_rate(seed: int) -> None:
    model = ImuModel("fast", (("sample_rate", {"hz": 250.0}),))
    sim = Simulation("ur5e", seed=seed, imu_model=model)
    rec = sim.advance(seconds=0.2)
    assert rec.n_samples == 50 and rec.sample_rate == pytest.approx(250.0)
    assert sim.robot.model.opt.timestep == pytest.approx(1 / 250.0)


def test_imu_seed_keeps_the_imus_errors_across_runs() -> None:
    """``imu_seed``: two runs with other motion and noise, the same drawn IMU errors (a real IMU keeps its
    gains, misalignments and biases from run to run); without it, each run draws its own."""
    a = Simulation("paper-1", seed=1, imu_seed=7)
    b = Simulation("paper-1", seed=2, imu_seed=7)
    c = Simulation("paper-1", seed=2)
    for name in ("gyro_matrix", "acc_matrix", "gyro_bias", "acc_bias"):
        assert np.array_equal(getattr(a.params, name), getattr(b.params, name)), name
    assert not np.allclose(a.params.gyro_matrix, c.params.gyro_matrix)
    assert not np.allclose(a.advance(50).q, b.advance(50).q)  # the motion is the seed's
