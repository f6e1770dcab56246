"""Forward kinematics of a fixed-base robot of revolute joints, as products of exponentials.

What a robot's model says its IMUs read, given its joint angles: the reference motion of the sensor
discrepancy analysis for robots with encoders (:mod:`bodyschema.discrepancy.encoders`). The model is
written in the product-of-exponentials form (Lynch & Park, *Modern Robotics*, §4.1): every joint is a
world axis through a world point at the zero pose (all angles 0), every IMU a world pose at the zero
pose, and the pose of an IMU at angles ``θ`` is ``exp([S_1] θ_1) ... exp([S_m] θ_m) T_k(0)`` over the
joints from the root to its link. No link frames, no Denavit-Hartenberg conventions: what a model file
or a simulator reads off its zero pose is all it needs (:func:`simulators.robot_chain.robot_chain`).

Example: a single joint about world z through the origin, an IMU 1 m out on x; a quarter turn puts
the IMU on y, and turning at 1 rad/s its gyro reads 1 rad/s about its own z.

>>> import numpy as np
>>> chain = RobotChain(("j",), (None,), np.array([[0.0, 0.0, 1.0]]), np.zeros((1, 3)),
...                    ("imu",), (0,), np.eye(3)[None], np.array([[1.0, 0.0, 0.0]]))
>>> R, p, omega = chain.motion(np.array([[np.pi / 2]]), np.array([[1.0]]))
>>> np.round(p[0, 0], 6).tolist()
[0.0, 1.0, 0.0]
>>> np.round(omega[0, 0], 6).tolist()
[0.0, 0.0, 1.0]
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["RobotChain", "axis_rotations"]


def axis_rotations(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations by ``angle`` (T,) about the unit ``axis`` (3,) (Rodrigues' formula)."""
    a = np.asarray(axis, dtype=np.float64)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


@dataclass(frozen=True)
class RobotChain:
    """A fixed-base robot of revolute joints at its zero pose, and the IMUs it carries.

    ``parent[j]``: index of joint ``j``'s parent joint (None: on the base); ``axis`` (N, 3) unit world
    axes and ``point`` (N, 3) a world point on each, at the zero pose; ``imu_joint[k]``: the joint
    that moves IMU ``k``'s link (None: the base); ``imu_R`` (K, 3, 3) sensor -> world and ``imu_p``
    (K, 3) the IMUs' world poses at the zero pose; ``zero`` (N,): the joint readings at that pose
    (None: all 0), subtracted from the angles :meth:`motion` is given.
    """

    joint_names: tuple[str, ...]
    parent: tuple[int | None, ...]
    axis: np.ndarray
    point: np.ndarray
    imu_names: tuple[str, ...]
    imu_joint: tuple[int | None, ...]
    imu_R: np.ndarray
    imu_p: np.ndarray
    zero: np.ndarray | None = None

    def __post_init__(self) -> None:
        n, k = len(self.joint_names), len(self.imu_names)
        if len(self.parent) != n or self.axis.shape != (n, 3) or self.point.shape != (n, 3):
            raise ValueError(f"a chain of {n} joints needs {n} parents, axes (N, 3) and points (N, 3)")
        if len(self.imu_joint) != k or self.imu_R.shape != (k, 3, 3) or self.imu_p.shape != (k, 3):
            raise ValueError(f"a chain with {k} IMUs needs {k} joints, rotations (K, 3, 3), positions (K, 3)")
        for j, p in enumerate(self.parent):
            seen = {j}
            while p is not None:
                if p in seen or not 0 <= p < n:
                    raise ValueError(f"joint {self.joint_names[j]!r}: its parents form no tree")
                seen.add(p)
                p = self.parent[p]
        if not np.allclose(np.linalg.norm(self.axis, axis=1), 1.0, atol=1e-6):
            raise ValueError("joint axes must be unit vectors")

    def subset(self, imu_names: tuple[str, ...] | list[str]) -> RobotChain:
        """The same robot carrying only the IMUs ``imu_names``, in that order."""
        k = [self.imu_names.index(n) for n in imu_names]
        return replace(
            self,
            imu_names=tuple(imu_names),
            imu_joint=tuple(self.imu_joint[i] for i in k),
            imu_R=self.imu_R[k],
            imu_p=self.imu_p[k],
        )

    def path(self, k: int) -> list[int]:
        """The joints from the root to IMU ``k``'s link, root first."""
        out: list[int] = []
        j = self.imu_joint[k]
        while j is not None:
            out.append(j)
            j = self.parent[j]
        return out[::-1]

    def motion(self, theta: np.ndarray, theta_dot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(R (T, K, 3, 3), p (T, K, 3), omega (T, K, 3))``: each IMU's world pose at joint angles
        ``theta`` (T, N), and its angular velocity in its own frame (what its gyro reads) at rates
        ``theta_dot`` (T, N)."""
        th = np.asarray(theta, dtype=np.float64)
        if self.zero is not None:
            th = th - self.zero
        thd = np.asarray(theta_dot, dtype=np.float64)
        T, K = th.shape[0], len(self.imu_names)
        R, p, omega = np.empty((T, K, 3, 3)), np.empty((T, K, 3)), np.empty((T, K, 3))
        cache: dict[tuple[int, ...], tuple[np.ndarray, ...]] = {
            (): (np.tile(np.eye(3), (T, 1, 1)), np.zeros((T, 3)), np.zeros((T, 3)))
        }
        for k in range(K):
            Ra, pa, wa = self._prefix(tuple(self.path(k)), th, thd, cache)
            R[:, k] = Ra @ self.imu_R[k]
            p[:, k] = pa + Ra @ self.imu_p[k]
            omega[:, k] = np.einsum("tba,tb->ta", R[:, k], wa)
        return R, p, omega

    def _prefix(
        self,
        path: tuple[int, ...],
        th: np.ndarray,
        thd: np.ndarray,
        cache: dict[tuple[int, ...], tuple[np.ndarray, ...]],
    ) -> tuple[np.ndarray, ...]:
        """Rotation, translation and world angular velocity of ``exp([S_1] θ_1) ... exp([S_m] θ_m)``
        along ``path`` (shared prefixes computed once)."""
        if path in cache:
            return cache[path]
        Rb, pb, wb = self._prefix(path[:-1], th, thd, cache)
        j = path[-1]
        Rj = axis_rotations(self.axis[j], th[:, j])
        pj = self.point[j] - Rj @ self.point[j]  # a rotation about the axis through point[j]
        w = wb + (Rb @ self.axis[j]) * thd[:, j, None]  # the joint's world axis now, times its rate
        out = (Rb @ Rj, pb + np.einsum("tab,tb->ta", Rb, pj), w)
        cache[path] = out
        return out
