"""Excitation plans: limits held on every written sample, bounded planning work, only the joints a
recording left open, and the CSV and MCAP outputs read back."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bodyschema.excitation_plan import (
    JointLimits,
    PlanOptions,
    check_limits,
    cubic_motion,
    finite_differences,
    maximal_groups,
    plan_excitation,
    regressor_cost,
)
from simulators.limits import DEFAULT_ACCELERATION, load_limits, model_limits

INERTIA = '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>'
URDF = f"""<robot name="arm">
  <link name="base"><inertial><mass value="1"/>{INERTIA}</inertial></link>
  <link name="l1"><inertial><mass value="0.5"/>{INERTIA}</inertial></link>
  <link name="l2"><inertial><mass value="0.3"/>{INERTIA}</inertial></link>
  <link name="l3"><inertial><mass value="0.2"/>{INERTIA}</inertial></link>
  <joint name="a" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-0.4" upper="0.3" velocity="0.5" effort="5"/></joint>
  <joint name="b" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.2"/><axis xyz="0 1 0"/>
    <limit lower="-1.0" upper="1.0" velocity="0.7" effort="5"/></joint>
  <joint name="c" type="continuous"><parent link="l2"/><child link="l3"/>
    <origin xyz="0 0 0.2"/><axis xyz="1 0 0"/>
    <limit velocity="2.0" effort="5"/></joint>
</robot>
"""

MJCF = """<mujoco model="two">
  <worldbody>
    <body name="l1"><joint name="a" type="hinge" axis="0 0 1" range="-20 30"/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>
      <body name="l2" pos="0.2 0 0"><joint name="b" type="hinge" axis="0 1 0" range="-1 1"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/></body></body>
  </worldbody>
  <actuator><velocity joint="a" kv="1" ctrlrange="-0.6 0.6"/></actuator>
</mujoco>
"""

TOML = """[defaults]
acceleration = 2.5

[joints.b]
lower = -0.2
upper = 0.25
velocity = 0.3
"""


def _limits(n: int, vel: float = 1.0, acc: float = 4.0, half: float = 2.0) -> JointLimits:
    names = tuple(f"j{i}" for i in range(n))
    return JointLimits(names, np.full(n, -half), np.full(n, half), np.full(n, vel), np.full(n, acc))


def _assert_within(plan, lim: JointLimits) -> None:  # type: ignore[no-untyped-def]
    """Every written sample, and the velocity and acceleration between samples, inside every limit."""
    assert check_limits(plan, lim) == []
    sub = lim.subset(plan.joint_names)
    v, a = finite_differences(plan.q, plan.rate)
    assert (plan.q >= sub.lower - 1e-12).all() and (plan.q <= sub.upper + 1e-12).all()
    assert (np.abs(v) <= sub.velocity + 1e-12).all()
    assert (np.abs(a) <= sub.acceleration + 1e-12).all()


def test_urdf_limits_are_read_and_respected(tmp_path: Path) -> None:
    path = tmp_path / "arm.urdf"
    path.write_text(URDF)
    lim = model_limits(str(path))
    assert lim.names == ("a", "b", "c")
    assert lim.lower[:2].tolist() == [-0.4, -1.0] and lim.upper[:2].tolist() == [0.3, 1.0]
    assert lim.velocity.tolist() == [0.5, 0.7, 2.0]
    assert math.isinf(lim.lower[2]) and lim.acceleration.tolist() == [DEFAULT_ACCELERATION] * 3
    plan = plan_excitation(lim, np.zeros(3), 30.0)
    _assert_within(plan, lim)
    # the tight joint uses its room: a plan that respects limits by not moving would pass the check
    assert plan.q[:, 0].max() > 0.2 or plan.q[:, 0].min() < -0.25


def test_mjcf_range_and_velocity_ctrlrange_are_read_and_respected(tmp_path: Path) -> None:
    path = tmp_path / "two.xml"
    path.write_text(MJCF)
    lim = model_limits(str(path))
    assert np.allclose(lim.lower[0], math.radians(-20)) and np.allclose(lim.upper[0], math.radians(30))
    assert lim.velocity.tolist() == [0.6, 1.0]
    plan = plan_excitation(lim, np.zeros(2), 12.0, options=PlanOptions(rate=250.0))
    _assert_within(plan, lim)
    assert np.abs(np.diff(plan.q[:, 0])).max() * 250 > 0.5 * 0.6  # it moves near its speed limit


def test_limits_file_overrides_the_model(tmp_path: Path) -> None:
    urdf, toml = tmp_path / "arm.urdf", tmp_path / "lim.toml"
    urdf.write_text(URDF)
    toml.write_text(TOML)
    lim = load_limits(str(urdf), str(toml))
    assert lim.lower[1] == -0.2 and lim.upper[1] == 0.25 and lim.velocity[1] == 0.3
    assert lim.acceleration.tolist() == [2.5, 2.5, 2.5] and lim.velocity[0] == 0.5
    plan = plan_excitation(lim, np.zeros(3), 20.0)
    _assert_within(plan, lim)
    alone = load_limits(None, str(toml))
    assert alone.names == ("b",) and alone.velocity[0] == 0.3 and alone.acceleration[0] == 2.5
    (tmp_path / "bad.toml").write_text("[joints.zz]\nlower = 0\n")
    with pytest.raises(ValueError, match="unknown joint"):
        load_limits(str(urdf), str(tmp_path / "bad.toml"))
    (tmp_path / "typo.toml").write_text("[joints.a]\nvelocty = 1\n")
    with pytest.raises(ValueError, match="unknown key"):
        load_limits(str(urdf), str(tmp_path / "typo.toml"))


@pytest.mark.parametrize("n", [1, 2, 5, 26])
def test_every_sample_within_limits_and_work_bounded(n: int) -> None:
    lim = _limits(n, vel=0.8, acc=3.0, half=1.2)
    opts = PlanOptions(seed=3)
    start = np.linspace(-1.0, 1.0, n)  # some joints start near a limit
    plan = plan_excitation(lim, start, 60.0, options=opts)
    _assert_within(plan, lim)
    assert np.allclose(plan.q[0], start) and np.allclose(plan.q[-1], start, atol=1e-9)  # rest to rest
    # bounded planning work: the search stops at its evaluation budget, whatever the luck
    assert plan.evaluations <= opts.max_evaluations + opts.candidates + 64
    assert plan.decide_s is not None and plan.cond <= opts.target_cond
    # a single joint decides fastest alone (one segment); many joints fastest together (Fourier)
    assert plan.method == ("staggered" if n <= 2 else "fourier")
    if n == 26:
        assert plan.decide_s < n * opts.segment  # sooner than one joint at a time


def test_cost_is_the_worst_normalised_condition_number() -> None:
    t = np.linspace(0, 6 * np.pi, 600, endpoint=False)  # whole periods: exactly orthogonal
    same = np.stack([np.sin(t), 2 * np.sin(t)], 1)
    assert regressor_cost(same, []) > 1e6
    ortho = np.stack([np.sin(t), np.cos(t), np.sin(2 * t)], 1)
    assert regressor_cost(ortho, maximal_groups([[0, 1, 2], [0, 1]])) < 1.1
    assert [g.tolist() for g in maximal_groups([[0], [0, 1], [2, 1, 0], [3]])] == [[0, 1, 2], [3]]


def test_held_joints_do_not_move() -> None:
    lim = _limits(4)
    plan = plan_excitation(lim, np.zeros(4), 10.0, excite=["j2"])
    assert plan.excited == ("j2",)
    assert np.ptp(plan.q[:, [0, 1, 3]]) == 0.0 and np.ptp(plan.q[:, 2]) > 0.5
    empty = plan_excitation(lim, np.zeros(4), 10.0, excite=[])
    assert empty.method == "none" and np.ptp(empty.q) == 0.0 and empty.reason


@pytest.mark.slow
def test_cli_recording_plans_only_the_undetermined_joint_and_outputs_read_back(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from cli.main import main
    from simulators.excitation import Observable
    from simulators.recording_io import save_recording
    from simulators.simulation import simulate

    class OneStill(Observable):
        def _bind(self, robot, rng):  # type: ignore[no-untyped-def]
            super()._bind(robot, rng)
            self.a_[2] = 0.0
            self.center_[2] = self.q0_[2]

    rec = simulate("paper-2", seconds=20.0, seed=0, excitation=OneStill())  # synced: the fast path
    path = tmp_path / "rec.npz"
    save_recording(rec, path)
    csv = tmp_path / "plan.csv"
    assert (
        main(["excite", "--model", "paper-2", "--recording", str(path), "--seconds", "10", "-o", str(csv)])
        == 0
    )
    head = csv.read_text().splitlines()[0].split(",")
    data = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert head == ["time", "j1", "j2", "j3", "j4", "j5"] and data.shape == (1001, 6)
    moved = np.ptp(data[:, 1:], axis=0) > 1e-9
    # j3, left undetermined, and j2, whose IMUs' lever arms (with j3's link merged into j2's, as the
    # data show it) stayed above the 5 mm convergence bound; j1, j4, j5 decided and converged: still
    assert moved.tolist() == [False, True, True, False, False]
    assert np.allclose(data[0, 1:], rec.q[-1])  # from the recording's last pose
    lim = model_limits("paper-2")
    v, a = finite_differences(data[:, 1:], 100.0)
    assert (np.abs(v) <= lim.velocity).all() and (np.abs(a) <= lim.acceleration).all()

    bag = tmp_path / "plan.mcap"
    assert main(["excite", "--model", "ur5e", "--seconds", "6", "-o", str(bag)]) == 0
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert len(msgs) == 1 and msgs[0].joint_names[0] == "shoulder_pan"
    pts = msgs[0].points
    q = np.array([p.positions for p in pts])
    assert q.shape == (601, 6) and pts[-1].time_from_start.sec == 6
    ur = model_limits("ur5e")
    v, a = finite_differences(q, 100.0)
    assert (np.abs(v) <= ur.velocity).all() and (np.abs(a) <= ur.acceleration).all()
    assert main(["excite", "--model", "ur5e", "--seconds", "6", "-o", str(bag)]) == 1  # never overwrites


def test_a_range_away_from_zero_is_checked_as_it_is() -> None:
    # a knee bent -2.6..-0.2 rad: a plan inside it is within limits, one step past -0.2 is not
    lim = JointLimits(("knee",), np.array([-2.6]), np.array([-0.2]), np.ones(1), np.full(1, 4.0))
    plan = plan_excitation(lim, np.array([-0.3]), 10.0)
    assert check_limits(plan, lim) == [] and plan.q.max() <= -0.2
    over = type(plan)(plan.joint_names, plan.rate, plan.t, plan.q + 0.2, plan.excited, plan.method, None, 1.0)
    assert check_limits(over, lim) and "position" in check_limits(over, lim)[0]


def _unexplained_speed_sq(q: np.ndarray, rate: float) -> np.ndarray:
    """Per joint, the RMS of ``q̇²`` left after regressing it on ``1, cos q, sin q``: what informs a
    lever arm's centripetal term beside gravity turning with the joint (module docstring)."""
    v = np.gradient(q, 1 / rate, axis=0)
    out = []
    for j in range(q.shape[1]):
        X = np.c_[np.ones(len(q)), np.cos(q[:, j]), np.sin(q[:, j])]
        y = v[:, j] ** 2
        out.append(np.sqrt(np.mean((y - X @ np.linalg.lstsq(X, y, rcond=None)[0]) ** 2)))
    return np.array(out)


def test_cubic_starts_and_stops_at_rest_with_its_derivatives() -> None:
    t = np.arange(20001) * 1e-3
    freq, delay = np.array([0.15, 0.2, 0.25]), np.array([0.0, 0.4, 1.0])
    d, v, a = cubic_motion(t, freq, delay, 20.0)
    assert np.allclose(np.gradient(d, t, axis=0)[1:-1], v[1:-1], atol=1e-4)
    assert np.allclose(np.gradient(v, t, axis=0)[1:-1], a[1:-1], atol=1e-2)
    for j in range(3):
        moving = np.flatnonzero(np.abs(v[:, j]) > 0)
        first, last = t[moving[0]], t[moving[-1]]
        assert first == pytest.approx(delay[j], abs=2e-3)
        # it stops at its last return to the centre: a whole number of half periods
        assert ((last - delay[j]) * 2 * freq[j]) % 1 == pytest.approx(0, abs=1e-2) or (
            ((last - delay[j]) * 2 * freq[j]) % 1 == pytest.approx(1, abs=1e-2)
        )
        assert last <= 20.0 and abs(d[-1, j]) < 1e-12
        assert np.abs(d[moving[[0, -1]], j]).max() < 1e-6 and np.abs(a[moving[[0, -1]], j]).max() < 0.05


def test_the_cubic_informs_lever_arms_more_than_the_free_series() -> None:
    lim = _limits(5, vel=1.0, acc=4.0, half=2.0)
    plans = {
        shape: plan_excitation(lim, np.zeros(5), 60.0, options=PlanOptions(shape=shape))
        for shape in ("cubic", "free")
    }
    for plan in plans.values():
        _assert_within(plan, lim)
        assert np.allclose(plan.q[0], 0.0) and np.allclose(plan.q[-1], 0.0, atol=1e-9)
    cubic, free = (_unexplained_speed_sq(plans[s].q, 100.0) for s in ("cubic", "free"))
    assert cubic.min() > 0.25 and free.max() < 0.24, (cubic, free)
    # the same tree-deciding prefix first, then back at rest at the start pose: the cubic follows
    assert plans["cubic"].decide_s == plans["free"].decide_s == 5.0
    between = round((5.0 + PlanOptions().ramp) * 100)
    assert np.abs(plans["cubic"].q[between]).max() < 1e-9
    assert np.ptp(plans["cubic"].q[:between], axis=0).min() > 0.3
