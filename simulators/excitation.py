"""How the simulated robots move: the paper's random torque, the UR5e sine, and motion that shows
every joint.

Excitation quality decides what a body schema learner can see. Uniform random torque (the paper's
simulated experiment) barely moves joints that carry heavy subtrees; :class:`Observable` tracks random
smooth per-joint targets with gravity compensation so every joint moves by a similar amount.

Each excitation is open loop in the actuator space the builder adds (``<j>:torque`` motors and
``<j>:pos``/``<j>:vel`` servos whose gains :meth:`Excitation.configure` sets), so commands are a pure
function of time: chunked and one-shot runs with the same seed give the same motion.

Example
-------
>>> import numpy as np
>>> from simulators.robot import Robot
>>> robot = Robot.from_catalog("ur5e")
>>> exc = make_excitation("sine").bind(robot, np.random.default_rng(0))
>>> exc.targets(np.array([0.0]))[2].round(3).tolist()[0][:2]
[0.02, 0.04]
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import mujoco
import numpy as np

from simulators.robot import Robot

__all__ = [
    "EXCITATIONS",
    "Excitation",
    "Hold",
    "Observable",
    "Poses",
    "RandomTorque",
    "SineVelocity",
    "excitation_rms",
    "make_excitation",
]

#: Paper Table I (UR5e): joint-velocity frequencies k (Hz) and phases y (rad).
TABLE_I_FREQS = (0.1, 0.13, 0.15, 0.17, 0.19, 0.21)
TABLE_I_PHASES = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)


def excitation_rms(qd: np.ndarray) -> np.ndarray:
    """Per-joint excitation: RMS joint velocity (rad/s) over a recording, shape (N,)."""
    qd = np.asarray(qd, dtype=np.float64)
    return np.sqrt(np.mean(qd**2, axis=0)) if qd.shape[0] else np.zeros(qd.shape[1])


class Excitation(ABC):
    """Commands for a robot's drive actuators. Hyper-parameters in ``__init__``; :meth:`bind` draws the
    per-joint state (ending in ``_``) from an injected generator and returns self."""

    name = ""

    def bind(self, robot: Robot, rng: np.random.Generator) -> Excitation:
        self.n_joints_ = robot.n_joints
        self.q0_ = robot.q()
        self.rng_ = rng
        self._bind(robot, rng)
        self.configure(robot)
        return self

    def _bind(self, robot: Robot, rng: np.random.Generator) -> None:  # noqa: B027 - optional hook
        pass

    @abstractmethod
    def configure(self, robot: Robot) -> None:
        """Set servo gains and gravity compensation on the compiled model (again after a recompile)."""

    @abstractmethod
    def targets(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Torque, position target and velocity target per sample and joint, each (T, N)."""

    def ctrl(self, robot: Robot, t: np.ndarray) -> np.ndarray:
        """The full ``ctrl`` rows (T, nu) for sample times ``t``."""
        tau, qt, vt = self.targets(np.asarray(t, dtype=np.float64))
        out = np.zeros((len(t), robot.model.nu))
        for cols, vals in ((robot.act_torque, tau), (robot.act_pos, qt), (robot.act_vel, vt)):
            ok = cols >= 0
            out[:, cols[ok]] = vals[:, ok]
        return out


def _set_servo(robot: Robot, kp: np.ndarray, kv: np.ndarray) -> None:
    m = robot.model
    for j in range(robot.n_joints):
        a, b = robot.act_pos[j], robot.act_vel[j]
        if a >= 0:
            m.actuator_gainprm[a, 0] = kp[j]
            m.actuator_biasprm[a, 1] = -kp[j]
        if b >= 0:
            m.actuator_gainprm[b, 0] = kv[j]
            m.actuator_biasprm[b, 2] = -kv[j]


def _joint_inertia(robot: Robot) -> np.ndarray:
    m, d = robot.model, robot.data
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    return np.maximum(np.diag(full)[robot.dof_adr], 1e-4)


class RandomTorque(Excitation):
    """The paper's excitation: a uniform random torque per joint, renewed every ``period`` seconds.

    The torque bound of joint j is ``scale`` times the gravity torque about its axis at the initial
    pose plus ``accel`` (rad/s²) times its inertia; each drive has viscous friction with time constant
    ``friction_time`` (s). No gravity compensation, so heavy subtrees move little (as in the paper).
    """

    name = "random-torque"

    def __init__(
        self, period: float = 0.2, scale: float = 0.8, accel: float = 6.0, friction_time: float = 0.5
    ) -> None:
        self.period = period
        self.scale = scale
        self.accel = accel
        self.friction_time = friction_time

    def _bind(self, robot: Robot, rng: np.random.Generator) -> None:
        m, d = robot.model, robot.data
        mujoco.mj_forward(m, d)
        inertia = _joint_inertia(robot)
        bound = np.empty(robot.n_joints)
        for i, name in enumerate(robot.joint_names):
            j = m.joint(name).id
            b = int(m.jnt_bodyid[j])
            lever = d.subtree_com[b] - d.xanchor[j]
            weight = float(m.body_subtreemass[b]) * np.asarray(m.opt.gravity)
            gravity_torque = abs(float(np.dot(np.cross(lever, weight), d.xaxis[j])))
            bound[i] = self.scale * gravity_torque + self.accel * inertia[i]
        self.bound_ = bound
        self.levels_: list[np.ndarray] = []

    def configure(self, robot: Robot) -> None:
        # the velocity servo, commanded to zero, acts as the drive's viscous friction (time constant
        # ``friction_time``): without it a joint with no gravity load random-walks to any speed
        if not hasattr(self, "kv_"):
            self.kv_ = _joint_inertia(robot) / self.friction_time
        _set_servo(robot, np.zeros(robot.n_joints), self.kv_)
        robot.set_gravcomp(0.0)

    def targets(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        seg = np.floor(t / self.period + 1e-9).astype(np.int64)
        need = int(seg.max(initial=-1)) + 1
        while len(self.levels_) < need:  # drawn in segment order: chunking does not change the draws
            self.levels_.append(self.rng_.uniform(-1.0, 1.0, self.n_joints_) * self.bound_)
        tau = np.array([self.levels_[s] for s in seg]).reshape(len(t), self.n_joints_)
        zero = np.zeros_like(tau)
        return tau, zero, zero


class _Tracking(Excitation):
    """PD tracking of smooth joint targets with gravity compensation (servo bandwidth ``bandwidth`` Hz)."""

    def __init__(self, bandwidth: float = 4.0, damping_ratio: float = 1.0) -> None:
        self.bandwidth = bandwidth
        self.damping_ratio = damping_ratio

    def configure(self, robot: Robot) -> None:
        # gains are sized once, on the intact robot: after damage (a broken link) the same drive
        # keeps the same gains
        if not hasattr(self, "kp_"):
            inertia = _joint_inertia(robot)
            w = 2.0 * math.pi * self.bandwidth
            self.kp_, self.kv_ = inertia * w**2, 2.0 * self.damping_ratio * inertia * w
        _set_servo(robot, self.kp_, self.kv_)
        robot.set_gravcomp(1.0)


class SineVelocity(_Tracking):
    """Paper Table I: joint j tracks velocity ``A sin(2π k_j t + y_j)`` (and its integral as position).

    With more than six joints the frequencies repeat, raised 5 % per round so no two joints share one.
    """

    name = "sine"

    def __init__(
        self,
        amplitude: float = 0.2,
        freqs: tuple[float, ...] = TABLE_I_FREQS,
        phases: tuple[float, ...] = TABLE_I_PHASES,
        bandwidth: float = 4.0,
    ) -> None:
        super().__init__(bandwidth=bandwidth)
        self.amplitude = amplitude
        self.freqs = freqs
        self.phases = phases

    def _bind(self, robot: Robot, rng: np.random.Generator) -> None:
        n = robot.n_joints
        self.k_ = np.array(
            [self.freqs[j % len(self.freqs)] * (1 + 0.05 * (j // len(self.freqs))) for j in range(n)]
        )
        self.y_ = np.array([self.phases[j % len(self.phases)] for j in range(n)])

    def targets(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = 2.0 * math.pi * self.k_
        arg = np.outer(t, w) + self.y_
        vel = self.amplitude * np.sin(arg)
        pos = self.q0_ + self.amplitude / w * (np.cos(self.y_) - np.cos(arg))
        return np.zeros_like(pos), pos, vel


class Observable(_Tracking):
    """Every joint follows its own random smooth target: ``components`` sinusoids with frequencies in
    ``band`` (Hz) and a total amplitude of ``amplitude`` rad (less where the joint's range is tighter)
    about a centre inside the range, reached from the initial pose over the first ``ramp`` seconds.
    Gravity-compensated PD, so heavy subtrees move as much as light ones.
    """

    name = "observable"

    def __init__(
        self,
        amplitude: float = 0.7,
        band: tuple[float, float] = (0.1, 0.5),
        components: int = 3,
        bandwidth: float = 4.0,
        ramp: float = 1.0,
    ) -> None:
        super().__init__(bandwidth=bandwidth)
        self.amplitude = amplitude
        self.band = band
        self.components = components
        self.ramp = ramp

    def _bind(self, robot: Robot, rng: np.random.Generator) -> None:
        n, c = robot.n_joints, self.components
        m = robot.model
        amp = np.full(n, self.amplitude)
        lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
        for i, name in enumerate(robot.joint_names):
            j = m.joint(name).id
            if m.jnt_limited[j]:
                lo[i], hi[i] = m.jnt_range[j]
                amp[i] = min(amp[i], 0.45 * (hi[i] - lo[i]))
        # move about a centre inside the range (the start pose may sit near a limit)
        self.center_ = np.clip(self.q0_, lo + amp, hi - amp)
        self.lo_, self.hi_ = lo + 0.02, hi - 0.02
        # one frequency in each of ``components`` equal slices of the band: every joint gets a fast
        # component too, so none is left barely moving by an unlucky draw
        width = (self.band[1] - self.band[0]) / c
        self.f_ = self.band[0] + width * (np.arange(c) + rng.uniform(0.0, 1.0, size=(n, c)))
        self.phi_ = rng.uniform(0.0, 2.0 * math.pi, size=(n, c))
        wts = rng.uniform(0.5, 1.0, size=(n, c))
        self.a_ = amp[:, None] * wts / wts.sum(axis=1, keepdims=True)

    def targets(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        w = 2.0 * math.pi * self.f_  # (N, C)
        arg = t[:, None, None] * w + self.phi_  # (T, N, C)
        # from the start pose to the centre of the motion over the first ``ramp`` seconds (smoothly:
        # a jump would kick the robot)
        u = np.clip(t / self.ramp, 0.0, 1.0)[:, None]
        shift = self.center_ - self.q0_
        pos = self.q0_ + shift * (0.5 - 0.5 * np.cos(np.pi * u))
        pos = pos + np.sum(self.a_ * (np.sin(arg) - np.sin(self.phi_)), axis=2)
        vel = shift * np.where(u < 1.0, 0.5 * np.pi / self.ramp * np.sin(np.pi * u), 0.0)
        vel = vel + np.sum(self.a_ * w * np.cos(arg), axis=2)
        clipped = (pos < self.lo_) | (pos > self.hi_)
        pos = np.clip(pos, self.lo_, self.hi_)
        vel = np.where(clipped, 0.0, vel)
        return np.zeros_like(pos), pos, vel


class Hold(_Tracking):
    """Stand still at the initial pose (gravity-compensated PD): static recordings for calibration."""

    name = "hold"

    def targets(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pos = np.broadcast_to(self.q0_, (len(t), self.n_joints_)).copy()
        zero = np.zeros_like(pos)
        return zero, pos, zero


class Poses(_Tracking):
    """A new random pose every ``dwell`` seconds, reached by a smooth ``move`` (s) ramp and then held:
    static readings in many orientations, as in a multi-position accelerometer calibration."""

    name = "poses"

    def __init__(
        self, dwell: float = 1.5, move: float = 0.7, amplitude: float = 1.2, bandwidth: float = 4.0
    ) -> None:
        super().__init__(bandwidth=bandwidth)
        self.dwell = dwell
        self.move = move
        self.amplitude = amplitude

    def _bind(self, robot: Robot, rng: np.random.Generator) -> None:
        m = robot.model
        lo, hi = self.q0_ - self.amplitude, self.q0_ + self.amplitude
        for i, name in enumerate(robot.joint_names):
            j = m.joint(name).id
            if m.jnt_limited[j]:
                lo[i] = max(lo[i], m.jnt_range[j][0] + 0.05)
                hi[i] = min(hi[i], m.jnt_range[j][1] - 0.05)
        self.lo_, self.hi_ = lo, hi
        self.poses_: list[np.ndarray] = [self.q0_.copy()]

    def targets(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        seg = np.floor(t / self.dwell + 1e-9).astype(np.int64)
        while len(self.poses_) < int(seg.max(initial=0)) + 2:
            self.poses_.append(self.rng_.uniform(self.lo_, self.hi_))
        prev = np.array([self.poses_[max(s - 1, 0)] if s > 0 else self.poses_[0] for s in seg])
        nxt = np.array([self.poses_[s] for s in seg]).reshape(len(t), self.n_joints_)
        prev = prev.reshape(len(t), self.n_joints_)
        u = np.clip((t - seg * self.dwell) / self.move, 0.0, 1.0)[:, None]
        w = 0.5 - 0.5 * np.cos(np.pi * u)
        dw = np.where((u > 0) & (u < 1), 0.5 * np.pi * np.sin(np.pi * u) / self.move, 0.0)
        pos = prev + (nxt - prev) * w
        vel = (nxt - prev) * dw
        return np.zeros_like(pos), pos, vel


EXCITATIONS: dict[str, type[Excitation]] = {
    "random-torque": RandomTorque,
    "sine": SineVelocity,
    "observable": Observable,
    "hold": Hold,
    "poses": Poses,
}


def make_excitation(name: str | Excitation) -> Excitation:
    """An excitation by name (``random-torque``, ``sine``, ``observable``, ``hold``, ``poses``)."""
    if isinstance(name, Excitation):
        return name
    try:
        return EXCITATIONS[name]()
    except KeyError:
        raise ValueError(f"unknown excitation {name!r}; expected one of {', '.join(EXCITATIONS)}") from None
