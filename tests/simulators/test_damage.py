"""Each damage scenario changes the physics the way its ground truth says."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import numpy as np
import pytest

import simulators.damage
from bodyschema.findings import Diff
from simulators.damage import parse_damage
from simulators.simulation import Simulation, simulate


def _norms(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x, axis=-1)


def _sim(seed: int, robot: str = "paper-1", excitation: str = "observable") -> Simulation:
    return Simulation(robot, seed=seed, imu_model="ideal", excitation=excitation)


def _imus_on(sim: Simulation, joint: str | None) -> list[int]:
    truth = sim.truth().imu_joint
    return [k for k, n in enumerate(sim.robot.imu_names) if n in truth and truth[n] == joint]


def test_imu_moved_gyro_follows_its_new_link(seed: int) -> None:
    sim = _sim(seed)
    before = sim.advance(100)
    k = sim.robot.imu_names.index("imu3")
    ref_old = _imus_on(sim, "j1")[1]
    assert np.allclose(_norms(before.gyro[:, k]), _norms(before.gyro[:, ref_old]), atol=1e-9)
    diff = sim.apply_damage("imu_moved", imu="imu3", to="j4")
    assert diff.findings[0].from_ == "j1" and diff.findings[0].to == "j4"
    after = sim.advance(200)
    ref_new = next(i for i in _imus_on(sim, "j4") if i != k)
    # a rigid link: every IMU on it turns at the same rate
    assert np.allclose(_norms(after.gyro[:, k]), _norms(after.gyro[:, ref_new]), atol=1e-9)
    assert np.abs(_norms(after.gyro[:, k]) - _norms(after.gyro[:, ref_old])).max() > 0.1
    assert after.truth_imu_joint[k] == "j4" and sim.truth().imu_joint["imu3"] == "j4"
    assert sim.robot.model.site("imu3").bodyid[0] == sim.robot.model.body("link4").id


def test_imu_detached_follows_no_link(seed: int) -> None:
    sim = _sim(seed)
    sim.advance(50)
    sim.apply_damage("imu_detached", imu="imu30")
    rec = sim.advance(300)
    k = sim.robot.imu_names.index("imu30")
    truth = sim.truth()
    assert "imu30" not in truth.imu_joint
    assert json.loads(str(rec.extra["truth_imu_detached"])) == ["imu30"]
    assert k == 30
    # its gyro matches no link's
    for j in sim.robot.joint_names:
        ref = _imus_on(sim, j)[0]
        assert np.abs(_norms(rec.gyro[:, k]) - _norms(rec.gyro[:, ref])).max() > 0.05
    assert sim.robot.warnings() == {}


@pytest.mark.parametrize("mode", ["frozen", "zero"])
def test_imu_dead_stops_reporting(mode: str, seed: int) -> None:
    sim = Simulation("ur5e", seed=seed, imu_model="mpu6050")
    first = sim.advance(50)
    sim.apply_damage("imu_dead", imu="imu5", mode=mode)
    rec = sim.advance(100)
    k = 5
    expect_g = first.gyro[-1, k] if mode == "frozen" else np.zeros(3)
    expect_a = first.acc[-1, k] if mode == "frozen" else np.zeros(3)
    assert np.all(rec.gyro[:, k] == expect_g) and np.all(rec.acc[:, k] == expect_a)
    assert np.std(rec.gyro[:, 4], axis=0).max() > 0  # its neighbours still live


def test_joint_locked_seizes_while_commanded(seed: int) -> None:
    sim = _sim(seed)
    sim.advance(50)
    sim.apply_damage("joint_locked", joint="j2")
    rec = sim.advance(300)
    j = rec.joint_names.index("j2")
    assert np.ptp(rec.q[:, j]) < 5e-3  # seized
    _, target, _ = sim.excitation.targets(rec.t)
    assert np.ptp(target[:, j]) > 0.2  # while still commanded to move
    # the link of j2 now turns exactly like the link of j1
    a, b = _imus_on(sim, "j2")[0], _imus_on(sim, "j1")[0]
    assert np.abs(_norms(rec.gyro[5:, a]) - _norms(rec.gyro[5:, b])).max() < 0.05
    assert rec.extra["excitation"][j] < 0.02 < rec.extra["excitation"].max()


@pytest.mark.parametrize("mode", ["stuck", "offset"])
def test_encoder_fault_disagrees_with_the_body(mode: str, seed: int) -> None:
    healthy = _sim(seed).advance(200)
    sim = _sim(seed)
    sim.apply_damage("encoder_fault", joint="j3", mode=mode, value=0.4)
    rec = sim.advance(200)
    j = rec.joint_names.index("j3")
    assert np.allclose(rec.gyro, healthy.gyro)  # the body moves exactly as before
    if mode == "stuck":
        assert np.ptp(rec.q[:, j]) == 0.0 and np.ptp(healthy.q[:, j]) > 0.1
    else:
        assert np.allclose(rec.q[:, j], healthy.q[:, j] + 0.4)
    others = [i for i in range(5) if i != j]
    assert np.array_equal(rec.q[:, others], healthy.q[:, others])


def test_link_lost_subtree_no_longer_follows_its_joint(seed: int) -> None:
    sim = _sim(seed)
    before = sim.advance(100)
    k = _imus_on(sim, "j1")[0]
    j1 = before.joint_names.index("j1")
    # intact: link1 turns about j1's axis at exactly j1's rate
    assert np.allclose(_norms(before.gyro[:, k]), np.abs(before.qd[:, j1]), atol=1e-9)
    sim.apply_damage("link_lost", joint="j1")
    after = sim.advance(300)
    assert np.abs(_norms(after.gyro[:, k]) - np.abs(after.qd[:, j1])).mean() > 0.05
    assert np.ptp(after.q[:, j1]) > 0.1  # the motor and its encoder still turn
    _, _, detached = sim.robot.truth_arrays()
    assert detached[_imus_on(_sim(seed), "j1")].all() and not detached[_imus_on(_sim(seed), "j2")].any()
    assert sim.robot.warnings() == {}


def test_combined_damage_mid_run_via_simulate(seed: int) -> None:
    rec = simulate(
        "paper-6",
        seconds=2.0,
        seed=seed,
        imu_model="ideal",
        damage=["imu_moved:imu=imu0,to=j5,at=1.0", "joint_locked:joint=j4,at=0.5"],
    )
    diff = Diff.from_json(json.loads(str(rec.extra["truth_diff"])))
    assert [f.kind for f in diff.findings] == ["joint_locked", "imu_moved"]
    assert np.allclose(rec.extra["damage_time"], [0.5, 1.0])
    assert rec.truth_imu_joint[0] == "j5"
    j4 = rec.joint_names.index("j4")
    assert np.ptp(rec.q[50:, j4]) < 5e-3 < np.ptp(rec.q[:50, j4])
    assert rec.n_samples == 200 and np.all(np.diff(rec.t) > 0)


def test_damage_picks_parts_reproducibly(seed: int) -> None:
    a = _sim(seed).apply_damage("imu_moved")
    b = _sim(seed).apply_damage("imu_moved")
    assert a == b and a.findings[0].from_ != a.findings[0].to


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("imu_moved:imu=imu999", "unknown IMU 'imu999'"),
        ("joint_locked:joint=nope", "unknown joint 'nope'"),
        ("warp:x=1", "unknown damage 'warp'"),
        ("imu_dead:imu", "'imu' is not key=value"),
    ],
)
def test_bad_damage_is_a_clear_error(text: str, message: str, seed: int) -> None:
    with pytest.raises(ValueError, match=message):
        kind, kw = parse_damage(text)
        _sim(seed).apply_damage(kind, **kw)


def test_damage_as_a_tuple_of_strings_or_one_pair(seed: int) -> None:
    a = simulate("paper-1", 0.2, seed, imu_model="ideal", damage=("imu_dead:imu=imu1", "imu_dead:imu=imu2"))
    b = simulate("paper-1", 0.2, seed, imu_model="ideal", damage=("imu_dead", {"imu": "imu1"}))
    assert len(json.loads(str(a.extra["truth_diff"]))["findings"]) == 2
    assert json.loads(str(b.extra["truth_diff"]))["findings"][0]["imu"] == "imu1"


def test_damage_does_not_import_the_simulation() -> None:
    """The simulation imports damage, never the other way round: no import cycle, even for types."""
    tree = ast.parse(Path(simulators.damage.__file__).read_text())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)} | {
        a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names
    }
    assert "simulators.simulation" not in imported


@pytest.mark.parametrize("angle_deg", [2.0, 5.0])
def test_drift_damages_change_the_geometry_by_their_magnitude(angle_deg: float, seed: int) -> None:
    """The geometry-drift catalog, read back from the model: a turn about an axis perpendicular to the
    joint's turns the axis seen from the IMU by that angle; a slide moves the lever arm by its length
    (perpendicular to the axis, all of it visible); a bend turns the joint's world axis by its angle."""
    from simulators.kinematics_truth import axis_error_deg, kinematics_truth

    sim = _sim(seed)
    before = kinematics_truth(sim.robot)
    u = before["imu3"].axis
    about = np.cross(u, [1.0, 0.0, 0.0])
    sim.apply_damage("imu_rotated", imu="imu3", angle_deg=angle_deg, about=about.tolist())
    sim.apply_damage("imu_shifted", imu="imu2", meters=angle_deg * 1e-3)
    world = sim.robot.data.xaxis[sim.robot.model.joint("j3").id].copy()
    diff = sim.apply_damage("axis_changed", joint="j3", angle_deg=angle_deg)
    after = kinematics_truth(sim.robot)
    assert axis_error_deg(after["imu3"].axis, u) == pytest.approx(angle_deg, abs=1e-6)
    shift = after["imu2"].lever_arm - before["imu2"].lever_arm
    assert float(np.linalg.norm(shift)) == pytest.approx(angle_deg * 1e-3, abs=1e-9)
    sim.advance(1)  # the bent axis in the world, after the physics has run on the new model
    bent = sim.robot.data.xaxis[sim.robot.model.joint("j3").id]
    assert axis_error_deg(bent, world) == pytest.approx(angle_deg, abs=0.5)
    assert [f.kind for f in sim.findings] == ["imu_rotated", "imu_shifted", "axis_changed"]
    assert diff.findings[0].joint == "j3" and "bent" in diff.findings[0].detail


def test_backlash_encoder_leads_the_link_by_half_the_dead_band(seed: int) -> None:
    """``backlash``: the body moves as before; the encoder is half the dead band ahead of the link in the
    direction of motion, on both sides of every reversal, and keeps its side across chunks."""
    healthy = _sim(seed).advance(400)
    sim = _sim(seed)
    diff = sim.apply_damage("backlash", joint="j3", deg=2.0)
    first, second = sim.advance(200), sim.advance(200)
    j = first.joint_names.index("j3")
    assert np.allclose(np.concatenate([first.gyro, second.gyro]), healthy.gyro)  # the body is the same
    lead = np.concatenate([first.q[:, j], second.q[:, j]]) - healthy.q[:, j]
    assert np.allclose(np.abs(lead), np.radians(1.0))
    moving = np.abs(healthy.qd[:, j]) > 0.01
    assert np.array_equal(np.sign(lead[moving]), np.sign(healthy.qd[moving, j]))
    assert set(np.sign(lead).tolist()) == {-1.0, 1.0}  # the joint reversed in the run
    others = [i for i in range(healthy.q.shape[1]) if i != j]
    assert np.array_equal(first.q[:, others], healthy.q[:200, others])
    assert diff.findings[0].kind == "backlash" and diff.findings[0].joint == "j3"
