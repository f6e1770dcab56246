"""Builders of the science tests, shared by the tests of every layer: random out-trees, the small
branching robot of the signal-health tests with its exact gyro/encoder data, and simulated recordings
of a robot with the simulator's kinematic truth.

They live here, not in a test module, so that no test file imports another: each can be changed, split
or dropped on its own (tests/test_suite_rules.py holds the suite to that).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from hypothesis import strategies as st

from bodyschema.counting import parents_from_prufer
from bodyschema.outtree import OutTree
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from simulators.imu_model import ImuModel
from simulators.kinematics_truth import ImuTruth, kinematics_truth
from simulators.robot import Robot
from simulators.sensing import apply_sensing
from simulators.simulation import Simulation

__all__ = [
    "AXES",
    "LAYOUT",
    "Case",
    "chain_and_branch",
    "record",
    "rot_about",
    "synth",
    "trees",
    "truth_topology",
]


# ----------------------------------------------------------------------------------------- out-trees
@st.composite
def trees(draw: st.DrawFn, min_joints: int = 1, max_joints: int = 40) -> OutTree:
    """A labelled out-tree: uniform structure (Prüfer code) and a random link-joint pairing."""
    n = draw(st.integers(min_joints, max_joints))
    code = draw(st.lists(st.integers(0, n), min_size=max(n - 1, 0), max_size=max(n - 1, 0)))
    perm = draw(st.permutations(range(n)))
    parents = parents_from_prufer(code, n)
    joints = [f"q{k}" for k in range(n)]
    jp = {j: (None if p == 0 else joints[p - 1]) for j, p in zip(joints, parents, strict=True)}
    return OutTree.from_parents(jp, {j: f"imu{perm[k]}" for k, j in enumerate(joints)})


def chain_and_branch() -> OutTree:
    #  base -j1-> a -j2-> b -j4-> d
    #                \-j3-> c
    return OutTree.from_parents(
        {"j1": None, "j2": "j1", "j3": "j1", "j4": "j2"}, {"j1": "a", "j2": "b", "j3": "c", "j4": "d"}
    )


# ------------------------------------------------------------------- a small branching robot, exact
#: j1 (z axis) on the base, j2 (y axis) and j3 (x axis) both under j1; two IMUs on j1 and j2, one on j3.
LAYOUT = Topology(
    {"j1": None, "j2": "j1", "j3": "j1"},
    {"a1": "j1", "a2": "j1", "b1": "j2", "b2": "j2", "c1": "j3"},
    excitation={"j1": 0.5, "j2": 0.5, "j3": 0.5},
)
AXES = {"j1": np.array([0, 0, 1.0]), "j2": np.array([0, 1.0, 0]), "j3": np.array([1.0, 0, 0])}


def rot_about(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(T,3,3) rotation matrices about a unit axis (Rodrigues)."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def synth(
    rng: np.random.Generator,
    seconds: float = 20.0,
    rate: float = 100.0,
    *,
    locked: str | None = None,
    frozen_encoder: str | None = None,
    lost: str | None = None,
) -> Recording:
    """``seconds`` of the :data:`LAYOUT` robot: link gyros follow ω_child = R(q)ᵀ ω_parent + axis·q̇
    exactly, plus MPU-6050-like noise and bias, so a wrong judgement on it is the code's fault."""
    t = np.arange(int(seconds * rate)) / rate
    names = ("j1", "j2", "j3")
    q = np.zeros((t.size, 3))
    for k in range(3):
        f = rng.uniform(0.1, 0.25, 3)
        ph = rng.uniform(0, 2 * np.pi, 3)
        q[:, k] = sum(0.8 * np.sin(2 * np.pi * f[m] * t + ph[m]) for m in range(3))
    if locked is not None:
        q[:, names.index(locked)] = q[0, names.index(locked)]
    qd = np.gradient(q, t, axis=0)
    w1 = qd[:, [0]] * AXES["j1"]
    links = {"j1": w1}
    for j, k in (("j2", 1), ("j3", 2)):
        R = rot_about(AXES[j], q[:, k])
        links[j] = np.einsum("tji,tj->ti", R, w1) + qd[:, [k]] * AXES[j]
    if lost is not None:
        links[lost] = np.zeros_like(w1)  # the link lies still on the floor
    imus = ("a1", "a2", "b1", "b2", "c1")
    gyro = np.zeros((t.size, 5, 3))
    for n, name in enumerate(imus):
        mount = rot_about(rng.normal(size=3) / np.sqrt(3), np.array([rng.uniform(0, np.pi)]))[0]
        gyro[:, n] = links[LAYOUT.imu_joint[name]] @ mount.T + rng.normal(0, 0.3, 3)  # bias
        gyro[:, n] += rng.normal(0, 0.005, (t.size, 3))
    acc = np.tile([0.0, 0.0, 9.81], (t.size, 5, 1)) + rng.normal(0, 0.04, (t.size, 5, 3))
    q_enc = q.copy()
    if frozen_encoder is not None:
        q_enc[:, names.index(frozen_encoder)] = q_enc[0, names.index(frozen_encoder)]
    return Recording(t=t, joint_names=names, q=q_enc, imu_names=imus, acc=acc, gyro=gyro)


# ------------------------------------------------------------- simulated recordings with their truth
@dataclass(frozen=True)
class Case:
    rec: Recording
    truth: dict[str, ImuTruth]
    robot: Robot


def record(
    robot: Robot,
    seconds: float,
    seed: int,
    imu_model: str | ImuModel = "mpu6050",
    lock: str = "",
    damage: tuple[str, dict[str, Any]] | None = None,
    imu_seed: int | None = None,
) -> Case:
    """``seconds`` of ``robot`` at 1 kHz physics, then the ``robot`` sensing preset; ``damage`` (a kind of
    :mod:`simulators.damage` and its arguments) is applied first; ``imu_seed`` keeps the IMUs' errors
    from one run to the next."""
    sim = Simulation(robot, seed=seed, rate=1000.0, imu_model=imu_model, imu_seed=imu_seed)
    if lock:
        sim.apply_damage("joint_locked", joint=lock)
    if damage is not None:
        sim.apply_damage(damage[0], **damage[1])
    fine = sim.advance(seconds=seconds)
    rec = apply_sensing(fine, "robot", np.random.default_rng(seed + 1000))
    return Case(rec=rec, truth=kinematics_truth(robot), robot=robot)


def truth_topology(rec: Recording) -> Topology:
    return Topology(joint_parent=rec.truth_parent_map, imu_joint=rec.truth_imu_map)  # type: ignore[arg-type]
