"""Stance chains: a synthetic floating base with a known answer, and the two measured robot logs
(any chain named must be exactly one leg of the robot's URDF, read here only as the truth)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from bodyschema.recording import Recording
from bodyschema.stance_chains import chain_rates, floating_base_rule, limbs, stance_chains
from tests.robot_data import MAPS, ROBOTS


def _walker(seed: int = 0) -> Recording:
    """Two 3-joint legs and a 2-joint arm, every joint driven by one gait phase; the left foot stands
    for 1.2 s, then the right, with 0.4 s of double support between; the base gyro is the stance leg's
    chain rotation (flat foot), plus MPU-6050-like noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(3200) * 0.01
    ph = 2 * np.pi * t / 3.2
    q = np.c_[
        0.3 * np.sin(ph), 0.1 * np.sin(ph + 0.5), 0.4 * np.sin(ph + 1.0),  # l leg
        0.3 * np.sin(ph + np.pi), 0.1 * np.sin(ph + 3.6), 0.4 * np.sin(ph + 4.1),  # r leg
        0.2 * np.sin(ph + 0.3), 0.15 * np.sin(ph + 2.0),  # arm, same phase
    ]  # fmt: skip
    q += 0.02 * np.sin(np.outer(t, rng.uniform(1.5, 4.0, 8)) + rng.uniform(0, 6, 8))
    qd = np.gradient(q, t, axis=0)
    axes = rng.normal(size=(3, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    m = t % 3.2
    left, right = m < 1.2, (m >= 1.6) & (m < 2.8)
    # both feet down: the legs close a loop and agree; the base follows the left leg until mid-way
    # through double support, then the right (so the rotation is continuous in each single stance)
    on_left = (m < 1.4) | (m >= 3.0)
    w = np.zeros((t.size, 3))
    w[on_left] = -chain_rates(axes, q[on_left][:, :3], qd[on_left][:, :3])
    w[~on_left] = -chain_rates(axes * [1, -1, 1], q[~on_left][:, 3:6], qd[~on_left][:, 3:6])
    f = np.c_[np.where(~right, 400.0, 0.0), np.where(~left, 400.0, 0.0)] + rng.normal(0, 5, (t.size, 2))
    names = ("l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle", "arm_a", "arm_b")
    q = np.round(q / (2 * np.pi / 4096)) * (2 * np.pi / 4096)  # 12-bit encoders
    gyro = (w + rng.normal(0, 0.002, w.shape))[:, None, :]
    acc = np.zeros((t.size, 1, 3)) + np.array([0.0, 0.0, 9.81])
    return Recording(t=t, joint_names=names, q=q, imu_names=("base",), acc=acc, gyro=gyro,
                     extra={"lf_force": f[:, 0], "rf_force": f[:, 1]})  # fmt: skip


def test_limbs_are_runs_of_a_shared_first_token():
    assert limbs(("l_hip", "l_knee", "r_hip", "arm_a", "arm_b")) == [(0, 1), (2,), (3, 4)]


@pytest.mark.slow
def test_synthetic_walker_names_each_stance_leg():
    res = stance_chains(_walker())
    got = {p.phase: p.joints for p in res.chains}
    assert got["lf_force down"] == ("l_hip", "l_knee", "l_ankle")
    assert got["rf_force down"] == ("r_hip", "r_knee", "r_ankle")
    for p in res.chains:
        assert p.confidence > 0.999
    # the arm moves with the same phase but no exact chain through it fits
    fits = dict(next(p for p in res.phases if p.phase == "lf_force down").fits)
    assert fits["arm_a arm_b"] > 3 * fits["l_hip l_knee l_ankle"]


def test_no_forces_and_no_flag_is_a_fixed_base():
    rec = _walker()
    fixed = Recording(t=rec.t, joint_names=rec.joint_names, q=rec.q, imu_names=rec.imu_names,
                      acc=rec.acc, gyro=rec.gyro)  # fmt: skip
    assert floating_base_rule(fixed)[0] is False
    assert stance_chains(fixed).phases == ()
    flagged = Recording(t=rec.t, joint_names=rec.joint_names, q=rec.q, imu_names=rec.imu_names,
                        acc=rec.acc, gyro=rec.gyro, extra={"floating_base": np.array(True)})  # fmt: skip
    assert floating_base_rule(flagged) == (True, "the recording's floating_base flag")
    res = stance_chains(flagged)  # no forces: one phase, the whole walk, no single leg fits all of it
    assert [p.phase for p in res.phases] == ["unknown contacts"]
    assert res.chains == ()


# ------------------------------------------------------------------------------------- real logs
def _legs(urdf: Path, feet: tuple[str, ...]) -> dict[str, set[str]]:
    """Truth: the moving joints on the path from each foot link to the root, from the URDF."""
    root = ET.parse(urdf).getroot()
    up = {
        j.find("child").get("link"): (j.get("name"), j.find("parent").get("link"), j.get("type"))
        for j in root.findall("joint")
    }
    out = {}
    for foot in feet:
        link, joints = foot, set()
        while link in up:
            name, link, kind = up[link]
            if kind != "fixed":
                joints.add(name)
        out[foot] = joints
    return out


def _log(name: str):
    from sim2real.robot_logs import import_log

    paths = {
        "icub": (
            ROBOTS / "icub-walking" / "sync-walkingFrontAndBackGoodTrial.mat",
            "icub-walking.toml",
            "mat",
        ),
        "go1": (ROBOTS / "go1-trot" / "go1.csv", "go1-trot.toml", "csv"),
    }
    path, mp, fmt = paths[name]
    if not path.is_file():
        pytest.skip(f"robot log missing: {path}")
    return import_log(path, MAPS / mp, fmt)[0]


@pytest.mark.slow
def test_icub_chains_are_exactly_one_leg():
    rec = _log("icub")
    legs = _legs(ROBOTS / "icub-walking" / "iCubGenova04.urdf", ("l_sole", "r_sole"))
    res = stance_chains(rec)
    assert res.floating_base
    assert res.chains, "single stance on a flat foot names its leg"
    for p in res.chains:
        assert set(p.joints) in [legs["l_sole"], legs["r_sole"]], p.joints
    singles = {p.phase: p.joints for p in res.chains}
    assert singles.get("lf_force_z down", ())[:1] in ((), ("l_hip_pitch",))
    assert singles.get("rf_force_z down", ())[:1] in ((), ("r_hip_pitch",))
    for p in res.undetermined:
        assert p.reason and p.decide


@pytest.mark.slow
def test_go1_point_feet_leave_the_chain_undetermined():
    rec = _log("go1")
    legs = _legs(ROBOTS / "go1-trot" / "go1.urdf", ("FR_foot", "FL_foot", "RR_foot", "RL_foot"))
    res = stance_chains(rec)
    assert res.floating_base and res.phases
    for p in res.chains:
        assert set(p.joints) in list(legs.values()), p.joints
    for p in res.undetermined:
        assert p.reason and p.decide
    # point feet fix no rotation: no leg's chain explains the trunk's turning in the trot phases
    assert len(res.undetermined) >= 2
