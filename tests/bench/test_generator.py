"""The independent robot generator: its truth is its MuJoCo model's, its two shapes hold the same
samples, a seed gives the same robot, joints stay in their ranges."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from bench.generator import GeneratorOptions, generate, save_npz
from bench.generator_sensing import SensingSpec

SHORT = GeneratorOptions(joints=(6, 9), seconds=3.0)


def _ancestors(rec, joint: str) -> list[str]:
    parent = rec.truth_parent_map
    out = []
    while joint is not None:
        out.append(joint)
        joint = parent[joint]
    return out


@pytest.fixture(scope="module")
def gen():
    return generate(11, SHORT)


def test_truth_tree_is_the_models(gen):
    """Each joint's truth parent is the joint of its body's parent body in the compiled model, and
    each IMU's truth joint is the joint of the body carrying its site."""
    model = mujoco.MjModel.from_xml_string(gen.xml)

    def joint_of(body: int) -> str:
        return "" if body == 0 or model.body_jntnum[body] == 0 else model.joint(model.body_jntadr[body]).name

    rec = gen.multi
    for name, parent in zip(rec.joint_names, rec.truth_joint_parent, strict=True):
        body = model.jnt_bodyid[model.joint(name).id]
        assert joint_of(model.body_parentid[body]) == parent
    for name, joint in zip(rec.imu_names, rec.truth_imu_joint, strict=True):
        assert joint_of(model.site_bodyid[model.site(name).id]) == joint


def test_gyro_is_ancestors_axis_rates_within_the_noise_model(gen):
    """ω = S Rᵀ Σ_{j ∈ ancestors} a_j q̇_j + b (docs/design.md §3) at a few samples, from the model
    posed at the recorded positions, with the drawn sensitivity S and bias b: what is left is the
    white noise the error model adds (6 sigma over some 300 values: a false alarm below 1e-6), and
    the truth axes and lever arms are the model's in every IMU frame."""
    rec, err = gen.multi, gen.imu_errors
    model = mujoco.MjModel.from_xml_string(gen.xml)
    data = mujoco.MjData(model)
    jid = {n: model.joint(n).id for n in rec.joint_names}
    col = {n: i for i, n in enumerate(rec.joint_names)}
    for i in (7, 100, 213):
        for n in rec.joint_names:
            data.qpos[model.jnt_qposadr[jid[n]]] = rec.q[i, col[n]]
        mujoco.mj_kinematics(model, data)
        for k, (imu, joint) in enumerate(zip(rec.imu_names, rec.truth_imu_joint, strict=True)):
            R = data.site_xmat[model.site(imu).id].reshape(3, 3)
            w = sum(data.xaxis[jid[a]] * gen.qd_true[i, col[a]] for a in _ancestors(rec, joint))
            want = err.gyro_S[k] @ (R.T @ w) + err.gyro_bias[k]
            assert np.all(np.abs(rec.gyro[i, k] - want) < 6 * err.gyro_noise_std + 1e-5)
            a = data.xaxis[jid[joint]]
            r = data.site_xpos[model.site(imu).id] - data.xanchor[jid[joint]]
            np.testing.assert_allclose(rec.extra["truth_axis"][k], R.T @ a, atol=1e-9)
            np.testing.assert_allclose(rec.extra["truth_lever_arm"][k], R.T @ (r - (r @ a) * a), atol=1e-9)
    assert 0 < err.gyro_noise_std < 0.01  # 0.005 °/s/√Hz over 250 Hz: 1.4 mrad/s
    assert np.all(np.abs(err.gyro_bias) <= np.deg2rad(20)) and np.abs(err.gyro_bias).max() > np.deg2rad(2)


def test_accelerometer_reads_gravity_up_at_rest_within_its_errors():
    """A robot whose servos hold still (no sines): each accelerometer reads S Rᵀ(-g) + b."""
    still = GeneratorOptions(joints=(5, 5), seconds=1.0, sines=1, freq_hz=(1e-6, 1e-6))
    g = generate(2, still)
    model = mujoco.MjModel.from_xml_string(g.xml)
    data = mujoco.MjData(model)
    rec, err = g.multi, g.imu_errors
    for n, j in zip(rec.joint_names, range(rec.n_joints), strict=True):
        data.qpos[model.jnt_qposadr[model.joint(n).id]] = rec.q[-1, j]
    mujoco.mj_kinematics(model, data)
    for k, imu in enumerate(rec.imu_names):
        R = data.site_xmat[model.site(imu).id].reshape(3, 3)
        want = err.acc_S[k] @ (R.T @ np.array([0, 0, 9.81])) + err.acc_bias[k]
        # servo creep left: the joints' rates are held by a 4 /s position term, below 1e-3 rad/s here
        assert np.abs(rec.acc[-1, k] - want).max() < 6 * err.acc_noise_std + 0.01


def test_two_shapes_hold_the_same_samples():
    opts = GeneratorOptions(
        joints=(5, 7), seconds=2.0, encoder_rate=250.0, rate=50.0, sensing=SensingSpec(encoder_bits=12)
    )
    g = generate(4, opts)
    m, s = g.multi, g.single
    assert m.is_multirate and not s.is_multirate and s.qd is None and m.qd is None
    np.testing.assert_array_equal(m.t, s.t)
    np.testing.assert_array_equal(m.gyro, s.gyro)
    np.testing.assert_array_equal(m.acc, s.acc)
    assert m.t_q.size == 5 * m.t.size and m.t_q[1] == pytest.approx(1 / 250)
    np.testing.assert_array_equal(m.q[::5], s.q)  # the encoder samples taken at the IMU stamps
    step = 2 * np.pi / 4096
    np.testing.assert_allclose(m.q / step, np.round(m.q / step), atol=1e-9)
    assert m.truth_joint_parent == s.truth_joint_parent and m.truth_imu_joint == s.truth_imu_joint


def test_seed_gives_the_same_robot_and_another_seed_another(tmp_path):
    a, b, c = generate(5, SHORT), generate(5, SHORT), generate(6, SHORT)
    for x, y in ((a.multi, b.multi), (a.single, b.single)):
        for key in ("t", "q", "acc", "gyro"):
            np.testing.assert_array_equal(getattr(x, key), getattr(y, key))
    assert a.xml == b.xml and a.xml != c.xml
    save_npz(a.multi, tmp_path / "a.npz")
    with np.load(tmp_path / "a.npz") as f:
        assert set(f.files) >= {"t", "t_q", "q", "acc", "gyro", "truth_joint_parent", "truth_skew"}
        np.testing.assert_array_equal(f["gyro"], a.multi.gyro)
        assert json.loads(str(f["sensing"]))["dlpf_cfg"] is None


def test_joints_stay_in_their_ranges_and_skew_and_filter_are_stated():
    """References keep 0.1 rad inside each range; MuJoCo's limits are soft (the default solref lets a
    joint driven at its servo's torque limit sink a few hundredths of a radian into the stop), so the
    recorded positions may pass a limit by that, and no more than the margin."""
    opts = GeneratorOptions(joints=(12, 12), seconds=6.0, sensing=SensingSpec(dlpf=True, skew=0.006))
    g = generate(8, opts)
    lim = g.spec.limits[np.argsort(g.spec.joint_names)]
    over = np.maximum(lim[:, 0] - g.multi.q, g.multi.q - lim[:, 1])
    assert over.max() < 0.1
    assert np.ptp(g.multi.q, axis=0).max() > 0.5  # they move
    assert float(g.multi.extra["truth_skew"]) == pytest.approx(0.006 + 0.0048)
    assert json.loads(str(g.multi.extra["sensing"]))["dlpf_cfg"] == 3
