"""A simulated robot following an excitation plan (:mod:`bodyschema.excitation_plan`).

:class:`PlannedMotion` tracks the plan's positions (linearly interpolated, with the matching velocity
as the servo's feed-forward) from ``start`` s for the plan's length, with the same gravity-compensated
PD servo as the simulators' tracking excitations. Outside the plan it gives what ``base`` gives (a
tracking excitation: the farm's default ``observable``), blended over ``blend`` s after the plan so
the servo target does not jump; the joints the plan holds still keep the base's motion meanwhile.
Without a tracking base every joint follows the plan, and holds its last pose after it.

>>> import numpy as np
>>> from simulators.robot import Robot
>>> from bodyschema.excitation_plan import plan_excitation
>>> from simulators.limits import robot_limits
>>> robot = Robot.from_catalog("paper-1")
>>> plan = plan_excitation(robot_limits(robot), robot.q(), 4.0)
>>> exc = PlannedMotion(plan).bind(robot, np.random.default_rng(0))
>>> bool(np.allclose(exc.targets(np.array([1.0]))[1][0], plan.q[100]))
True
"""

from __future__ import annotations

import numpy as np

from bodyschema.excitation_plan import ExcitationPlan
from simulators.excitation import Excitation, Hold, Observable, Poses, SineVelocity
from simulators.robot import Robot

__all__ = ["PlannedMotion"]

_TRACKING = (Hold, Observable, Poses, SineVelocity)


class PlannedMotion(Hold):
    """Follow ``plan`` from ``start`` s (see the module docstring); ``base`` outside it."""

    name = "planned"

    def __init__(
        self, plan: ExcitationPlan, start: float = 0.0, base: Excitation | None = None, blend: float = 1.0
    ) -> None:
        super().__init__()
        self.plan = plan
        self.start = float(start)
        self.base = base if isinstance(base, _TRACKING) else None
        self.blend = float(blend)
        if self.base is not None:
            self.bandwidth, self.damping_ratio = self.base.bandwidth, self.base.damping_ratio

    def _bind(self, robot: Robot, rng: np.random.Generator) -> None:
        names = list(robot.joint_names)
        missing = [j for j in self.plan.joint_names if j not in names]
        if missing:
            raise ValueError(f"the plan names joints the robot lacks: {', '.join(missing)}")
        # with a base to follow, the joints the plan holds still keep the base's motion (slow, and
        # uncorrelated with the plan's); without one, every joint follows the plan
        moved = self.plan.excited if self.base is not None else self.plan.joint_names
        pick = [self.plan.joint_names.index(j) for j in moved]
        self.cols_ = np.array([names.index(j) for j in moved], dtype=np.intp)
        self.q_ = self.plan.q[:, pick]
        self.vel_ = np.gradient(self.q_, 1.0 / self.plan.rate, axis=0)

    def adopt(self, robot: Robot) -> PlannedMotion:
        """Bind to a robot already running (keep its pose and the base's state), gains as the base's."""
        self.n_joints_ = robot.n_joints
        self.q0_ = robot.q()
        self._bind(robot, np.random.default_rng(0))
        if self.base is not None and hasattr(self.base, "kp_"):
            self.kp_, self.kv_ = self.base.kp_, self.base.kv_
        self.configure(robot)
        return self

    @property
    def end(self) -> float:
        return self.start + self.plan.seconds

    def targets(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=np.float64)
        if self.base is not None:
            tau, pos, vel = (a.copy() for a in self.base.targets(t))
        else:
            pos = np.broadcast_to(self.q0_, (len(t), self.n_joints_)).copy()
            tau, vel = np.zeros_like(pos), np.zeros_like(pos)
        u = t - self.start
        inside = (u >= 0) & (u <= self.plan.seconds)
        last = self.q_[-1]
        after = u > self.plan.seconds
        if after.any():
            # back to the base's motion over ``blend`` s, from the plan's last pose
            if self.base is None:
                pos[np.ix_(after, self.cols_)] = last
                vel[np.ix_(after, self.cols_)] = 0.0
            else:
                s = np.clip((u[after] - self.plan.seconds) / self.blend, 0.0, 1.0)[:, None]
                w = 0.5 - 0.5 * np.cos(np.pi * s)
                cur = pos[np.ix_(after, self.cols_)]
                pos[np.ix_(after, self.cols_)] = last + w * (cur - last)
                vel[np.ix_(after, self.cols_)] *= w
        if inside.any():
            x = u[inside] * self.plan.rate
            i0 = np.clip(np.floor(x).astype(np.intp), 0, len(self.plan.t) - 2)
            f = (x - i0)[:, None]
            pos[np.ix_(inside, self.cols_)] = (1 - f) * self.q_[i0] + f * self.q_[i0 + 1]
            vel[np.ix_(inside, self.cols_)] = (1 - f) * self.vel_[i0] + f * self.vel_[i0 + 1]
            tau[inside] = 0.0
        before = u < 0
        if self.base is None and before.any():
            pos[np.ix_(before, self.cols_)] = self.q_[0]
        return tau, pos, vel
