"""Recorded joint accelerations: the qacc the accelerometers were computed with, through every path."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from simulators.simulation import Simulation, simulate


def _site_readings(sim: Simulation, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """Specific force of every IMU from the site Jacobians at recorded q, qd, qdd: (T, K, 3)."""
    r = sim.robot
    m = r.model
    d = mujoco.MjData(m)
    jacp, jacr, dp = np.zeros((3, m.nv)), np.zeros((3, m.nv)), np.zeros((3, m.nv))
    out = np.empty((len(q), r.n_imus, 3))
    for i in range(len(q)):
        d.qpos[r.qpos_adr], d.qvel[r.dof_adr] = q[i], qd[i]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        a = np.zeros(m.nv)
        a[r.dof_adr] = qdd[i]
        for k, s in enumerate(r.site_ids):
            mujoco.mj_jacSite(m, d, jacp, jacr, int(s))
            mujoco.mj_jacDot(m, d, dp, None, d.site_xpos[s], int(m.site_bodyid[s]))
            R = d.site_xmat[s].reshape(3, 3)
            out[i, k] = R.T @ (jacp @ a + dp @ d.qvel - m.opt.gravity)
    return out


def test_recorded_qdd_reproduces_the_accelerometers(seed: int) -> None:
    rec = simulate("ur5e", seconds=1.0, seed=seed, imu_model="ideal", excitation="random-torque")
    sim = Simulation("ur5e", seed=seed, imu_model="ideal")
    assert rec.qdd is not None and rec.qd is not None and rec.q is not None
    acc = _site_readings(sim, rec.q, rec.qd, rec.qdd)
    scale = np.abs(rec.acc).max()
    assert np.abs(acc - rec.acc).max() <= 1e-9 * scale
    # a difference of qd is not the acceleration at the sample under torques that switch
    fd = np.gradient(rec.qd, rec.t, axis=0)
    assert np.abs(_site_readings(sim, rec.q, rec.qd, fd) - rec.acc).max() > 1e3 * np.abs(acc - rec.acc).max()


def test_qdd_is_the_same_in_chunks_with_readahead_and_through_derived(seed: int) -> None:
    whole = simulate("paper-2", seconds=0.6, seed=seed, imu_model="ideal")
    sim = Simulation("paper-2", seed=seed, imu_model="ideal", readahead=0.25)
    parts = [sim.advance(n) for n in (7, 13, 20, 20)]
    assert np.array_equal(np.concatenate([p.qdd for p in parts]), whole.qdd)
    assert np.abs(whole.qdd).max() > 1.0  # it did accelerate
    assert whole.derived().qdd is whole.qdd  # recorded accelerations are not replaced by differences
    no_qdd = dataclasses.replace(whole, qdd=None).derived()
    assert not np.allclose(no_qdd.qdd, whole.qdd)


def test_a_stuck_encoder_reads_no_acceleration_an_offset_keeps_it(seed: int) -> None:
    base = simulate("paper-1", seconds=0.5, seed=seed, imu_model="ideal")
    stuck = simulate(
        "paper-1",
        seconds=0.5,
        seed=seed,
        imu_model="ideal",
        damage="encoder_fault:joint=j2,mode=stuck,at=0.2",
    )
    off = simulate(
        "paper-1",
        seconds=0.5,
        seed=seed,
        imu_model="ideal",
        damage="encoder_fault:joint=j3,mode=offset,value=0.3",
    )
    j2, j3 = base.joint_names.index("j2"), base.joint_names.index("j3")
    assert stuck.qdd is not None and base.qdd is not None and off.qdd is not None
    after = stuck.t >= 0.2 - 1e-9
    assert np.all(stuck.qdd[after, j2] == 0.0) and np.all(stuck.qd[after, j2] == 0.0)
    assert np.array_equal(stuck.qdd[~after], base.qdd[~after])
    assert np.abs(base.qdd[after, j2]).max() > 0.1  # the body still moved
    assert np.array_equal(off.qdd, base.qdd)  # the physics is unchanged by a faulty encoder
    assert np.allclose(off.q[:, j3], base.q[:, j3] + 0.3)
