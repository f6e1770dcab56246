"""Random kinematic trees with IMUs, simulated by plain forward kinematics (no dynamics, no MuJoCo).

Data for the topology estimators' tests and the scaling benchmark (any size, in milliseconds): a random
out-tree of hinge joints with random axes and offsets, IMUs at random poses on the links, smooth random
joint trajectories (sums of sinusoids), and an MPU-6050-like error model (bias, scale, cross-axis,
white noise). Gyro and accelerometer follow the rigid-body equations exactly: ``gyro = Rᵀ ω_link`` and
``acc = Rᵀ (p̈ − g)`` with ``p̈`` from a fine central difference of the analytic trajectory.

>>> import numpy as np
>>> rec = random_robot_recording(np.random.default_rng(0), n_joints=4, seconds=2.0)
>>> rec.q.shape, rec.gyro.shape[2]
((200, 4), 3)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bodyschema.recording import GRAVITY, Recording

__all__ = ["KinematicTree", "random_robot_recording", "random_tree", "rotation"]


def rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations about unit ``axis`` (3,) by ``angle`` (T,) -> (T, 3, 3)."""
    a = np.asarray(axis, dtype=float)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    s = np.sin(angle)[:, None, None]
    c = np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


class KinematicTree:
    """Hinge joints on an out-tree; joint ``i``'s parent index is ``parent[i]`` (-1 = base), parents first."""

    def __init__(self, parent: list[int], rng: np.random.Generator, link_scale: float = 0.3):
        self.parent = list(parent)
        n = len(parent)
        self.axis = [v / np.linalg.norm(v) for v in rng.normal(size=(n, 3))]
        self.offset = [rng.normal(scale=link_scale, size=3) for _ in range(n)]
        self.rot0 = [_random_rotation(rng) for _ in range(n)]

    @property
    def n_joints(self) -> int:
        return len(self.parent)

    def link_poses(self, q: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """World rotation (T,3,3) and position (T,3) of every child link; index -1 is not included."""
        T = q.shape[0]
        R: list[np.ndarray] = []
        p: list[np.ndarray] = []
        for j, par in enumerate(self.parent):
            Rp = np.broadcast_to(np.eye(3), (T, 3, 3)) if par < 0 else R[par]
            pp = np.zeros((T, 3)) if par < 0 else p[par]
            R.append(Rp @ self.rot0[j] @ rotation(self.axis[j], q[:, j]))
            p.append(pp + Rp @ self.offset[j])
        return R, p


def random_tree(rng: np.random.Generator, n_joints: int) -> list[int]:
    """Parent indices of a random out-tree (each joint under the base or an earlier joint)."""
    return [int(rng.integers(-1, j)) if j > 0 else -1 for j in range(n_joints)]


def _trajectory(rng: np.random.Generator, n: int, still: set[int]):
    freqs = rng.uniform(0.07, 0.9, size=(n, 4))
    phases = rng.uniform(0, 2 * np.pi, size=(n, 4))
    amps = rng.uniform(0.2, 0.6, size=(n, 4)) / (2 * np.pi * freqs) * 0.8
    offs = rng.uniform(-1, 1, size=n)
    for j in still:
        amps[j] = 0.0

    def q(t: np.ndarray) -> np.ndarray:
        arg = 2 * np.pi * freqs[None] * t[:, None, None] + phases[None]
        return offs + (amps[None] * np.sin(arg)).sum(-1)

    def qd(t: np.ndarray) -> np.ndarray:
        arg = 2 * np.pi * freqs[None] * t[:, None, None] + phases[None]
        return (amps[None] * 2 * np.pi * freqs[None] * np.cos(arg)).sum(-1)

    return q, qd


def random_robot_recording(
    rng: np.random.Generator,
    n_joints: int = 6,
    seconds: float = 20.0,
    rate: float = 100.0,
    imus_per_link: tuple[int, int] = (1, 2),
    base_imus: int = 1,
    bare_links: tuple[int, ...] = (),
    still: tuple[int, ...] = (),
    noise: bool = True,
    parent: list[int] | None = None,
) -> Recording:
    """A recording of a random robot (MPU-6050-like errors when ``noise``), ground truth included.

    ``bare_links`` lists joints whose child link carries no IMU; ``still`` lists joints held still.
    Joint and IMU names are shuffled so that no estimator can read the tree from the order.
    """
    parent = random_tree(rng, n_joints) if parent is None else parent
    tree = KinematicTree(parent, rng)
    t = np.arange(round(seconds * rate)) / rate
    qf, qdf = _trajectory(rng, n_joints, set(still))
    q, qd = qf(t), qdf(t)
    h = 1e-3
    R, p = tree.link_poses(q)
    _, p_plus = tree.link_poses(qf(t + h))
    R_plus, _ = tree.link_poses(qf(t + h))
    _, p_minus = tree.link_poses(qf(t - h))
    R_minus, _ = tree.link_poses(qf(t - h))
    motion = _LinkMotion(len(t), R, p, R_plus, p_plus, R_minus, p_minus, _link_omegas(tree, parent, R, qd), h)
    gyro_a, acc_a, imu_link = _imus(rng, motion, n_joints, imus_per_link, base_imus, bare_links)
    K = gyro_a.shape[1]
    if noise:
        _add_imu_errors(rng, gyro_a, acc_a, rate)

    jperm = rng.permutation(n_joints)
    jname = {j: f"j{int(jperm[j])}" for j in range(n_joints)}
    iperm = rng.permutation(K)
    order = np.argsort(jperm)  # joint columns in name order
    imu_order = np.argsort(iperm)
    return Recording(
        t=t,
        joint_names=[jname[j] for j in order],
        q=q[:, order],
        qd=qd[:, order],
        imu_names=[f"imu{int(iperm[k])}" for k in imu_order],
        acc=acc_a[:, imu_order],
        gyro=gyro_a[:, imu_order],
        truth_joint_parent=["" if parent[j] < 0 else jname[parent[j]] for j in order],
        truth_imu_joint=["" if imu_link[k] < 0 else jname[imu_link[k]] for k in imu_order],
    )


@dataclass(frozen=True)
class _LinkMotion:
    """Every link's pose at the samples and ``h`` either side of them, and its world angular velocity."""

    n: int  # samples
    R: list[np.ndarray]
    p: list[np.ndarray]
    R_plus: list[np.ndarray]
    p_plus: list[np.ndarray]
    R_minus: list[np.ndarray]
    p_minus: list[np.ndarray]
    omega: list[np.ndarray]
    h: float


def _link_omegas(
    tree: KinematicTree, parent: list[int], R: list[np.ndarray], qd: np.ndarray
) -> list[np.ndarray]:
    """World angular velocity of each link: its parent's plus its own axis (in world) times q̇."""
    omega: list[np.ndarray] = []
    for j, par in enumerate(parent):
        w_axis = R[j] @ tree.axis[j]
        base = np.zeros((len(qd), 3)) if par < 0 else omega[par]
        omega.append(base + w_axis * qd[:, j : j + 1])
    return omega


def _imus(
    rng: np.random.Generator,
    m: _LinkMotion,
    n_joints: int,
    imus_per_link: tuple[int, int],
    base_imus: int,
    bare_links: tuple[int, ...],
) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Ideal gyro and accelerometer readings (T, K, 3) of IMUs at random poses on the links, and each
    IMU's link (-1: the base)."""
    T = m.n
    gyro, acc, imu_link = [], [], []
    for link in range(-1, n_joints):
        if link in bare_links:
            continue
        count = base_imus if link < 0 else int(rng.integers(imus_per_link[0], imus_per_link[1] + 1))
        for _ in range(count):
            Rm = _random_rotation(rng)
            r = rng.normal(scale=0.08, size=3)
            if link < 0:
                gyro.append(np.zeros((T, 3)))
                acc.append(np.broadcast_to(Rm.T @ (-GRAVITY), (T, 3)).copy())
            else:
                Rs = m.R[link] @ Rm
                gyro.append(np.einsum("tji,tj->ti", Rs, m.omega[link]))
                pp = m.p_plus[link] + m.R_plus[link] @ r
                pm = m.p_minus[link] + m.R_minus[link] @ r
                p0 = m.p[link] + m.R[link] @ r
                pdd = (pp - 2 * p0 + pm) / m.h**2
                acc.append(np.einsum("tji,tj->ti", Rs, pdd - GRAVITY))
            imu_link.append(link)
    return np.stack(gyro, axis=1), np.stack(acc, axis=1), imu_link


def _add_imu_errors(rng: np.random.Generator, gyro: np.ndarray, acc: np.ndarray, rate: float) -> None:
    """MPU-6050-like errors, in place: per-IMU scale, cross-axis and bias, then white noise."""
    deg = np.pi / 180
    for k in range(gyro.shape[1]):
        Sg = (
            np.eye(3)
            + np.diag(rng.uniform(-0.03, 0.03, 3))
            + rng.uniform(-0.02, 0.02, (3, 3)) * (1 - np.eye(3))
        )
        Sa = np.eye(3) + np.diag(rng.uniform(-0.03, 0.03, 3))
        gyro[:, k] = gyro[:, k] @ Sg.T + rng.uniform(-20, 20, 3) * deg
        acc[:, k] = acc[:, k] @ Sa.T + rng.uniform(-1, 1, 3) * np.array([0.05, 0.05, 0.08]) * 9.81
    gyro += rng.normal(scale=0.005 * deg * np.sqrt(rate / 2), size=gyro.shape)
    acc += rng.normal(scale=400e-6 * 9.81 * np.sqrt(rate / 2), size=acc.shape)
