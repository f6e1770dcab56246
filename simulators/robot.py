"""A compiled MuJoCo robot with IMUs: a thin physics wrapper, ideal IMU readings, ground truth.

:class:`Robot` steps the physics at its timestep and samples at ``rate``: at each sample it runs the
forward dynamics once, keeps what it needs (joint state, sensor readings, optionally site poses)
and integrates, so the recorded state and readings belong to the same instant. The ideal
accelerometer and gyro come from MuJoCo's own ``accelerometer`` and ``gyro`` sensors, evaluated only
at sampling instants (evaluating 100+ of them at every timestep costs more than the physics).

Ground truth is read from the compiled model only (``body_parentid``, ``jnt_bodyid``,
``site_bodyid``): :func:`truth_from_model`.

Example
-------
>>> robot = Robot.from_catalog("paper-1", rate=100.0)
>>> s = robot.sample(np.zeros((10, robot.model.nu)))
>>> s.acc.shape, round(float(s.t[-1]), 3)
((10, 60, 3), 0.09)
>>> robot.truth().joint_parent["j2"]
'j1'
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import mujoco
import numpy as np

from bodyschema.topology import Topology
from simulators.builder import LOOSE_PREFIX, instrument, load_spec, robot_joint_names

__all__ = ["Robot", "Samples", "truth_from_model"]

_J = mujoco.mjtJoint


@dataclass(frozen=True)
class Samples:
    """Ideal readings of one stretch of simulation: ``t`` (T,), ``q``/``qd``/``qdd`` (T,N), ``acc``/
    ``gyro``/``gyro_dot`` (T,K,3) in each sensor frame, ``R`` (T,K,3,3) sensor-to-world rotations.

    ``qdd`` is MuJoCo's ``qacc`` of the same forward pass the accelerometers are read from, so the
    readings follow exactly from ``q``, ``qd``, ``qdd`` through the site Jacobians (a finite difference
    of ``qd`` is only the mean acceleration over the interval and misses a torque that switches).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    gyro_dot: np.ndarray
    R: np.ndarray


def _body_joints(model: mujoco.MjModel) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {}
    for j in range(model.njnt):
        out.setdefault(int(model.jnt_bodyid[j]), []).append(j)
    return out


def truth_from_model(
    model: mujoco.MjModel, joint_names: tuple[str, ...] | None = None, imu_names: tuple[str, ...] = ()
) -> tuple[dict[str, str | None], dict[str, str | None], set[str]]:
    """Joint parents, IMU joints and detached IMUs, read from the compiled model.

    A joint's parent is the previous robot joint on its own body, else the last robot joint of the
    nearest ancestor body that has one (None: the base). An IMU rides the last joint of the nearest
    body (its own first) that has joints; if that joint was added by damage (a loose tether, a broken
    link) the IMU follows no robot joint and is reported detached instead. A free joint on a body
    directly under the world is a floating base and counts as the base.
    """
    robot = set(robot_joint_names(model))
    names = tuple(robot_joint_names(model)) if joint_names is None else joint_names
    on_body = _body_joints(model)

    def is_floating_base(j: int) -> bool:
        return _J(int(model.jnt_type[j])) == _J.mjJNT_FREE and model.body_parentid[model.jnt_bodyid[j]] == 0

    def last_robot_joint_above(body: int) -> str | None:
        b = body
        while b != 0:
            js = [model.joint(j).name for j in on_body.get(b, []) if model.joint(j).name in robot]
            if js:
                return js[-1]
            b = int(model.body_parentid[b])
        return None

    parents: dict[str, str | None] = {}
    for name in names:
        j = model.joint(name).id
        b = int(model.jnt_bodyid[j])
        before = [model.joint(i).name for i in on_body[b] if i < j and model.joint(i).name in robot]
        parents[name] = before[-1] if before else last_robot_joint_above(int(model.body_parentid[b]))

    imus: dict[str, str | None] = {}
    detached: set[str] = set()
    for imu in imu_names:
        b = int(model.site_bodyid[model.site(imu).id])
        owner: str | None = None
        while b != 0:
            js = [j for j in on_body.get(b, []) if not is_floating_base(j)]
            if js:
                last = model.joint(js[-1]).name
                if last in robot:
                    owner = last
                else:
                    detached.add(imu)
                break
            b = int(model.body_parentid[b])
        if imu not in detached:
            imus[imu] = owner
    return parents, imus, detached


def _integrator(model: mujoco.MjModel):
    kind = mujoco.mjtIntegrator(int(model.opt.integrator))
    if kind == mujoco.mjtIntegrator.mjINT_EULER:
        return mujoco.mj_Euler
    if kind == mujoco.mjtIntegrator.mjINT_RK4:
        return lambda m, d: mujoco.mj_RungeKutta(m, d, 4)
    return mujoco.mj_implicit


class Robot:
    """One simulated robot. ``spec`` stays editable: damage edits it and calls :meth:`recompile`.

    ``rate`` is the sample rate (Hz); the physics timestep is the largest ``1/(rate*n)`` not above
    ``max_timestep``. Joints are the robot joints of the model (named hinges/slides), IMUs are the
    sites named ``imuN`` carrying an accelerometer, in numeric order.
    """

    def __init__(
        self, spec: mujoco.MjSpec, *, name: str | None = None, rate: float = 100.0, max_timestep: float = 0.01
    ) -> None:
        if not rate > 0:
            raise ValueError("rate must be > 0")
        self.spec = spec
        self.name = name or spec.modelname or "robot"
        self.rate = float(rate)
        self.max_timestep = float(max_timestep)
        for body in spec.bodies:
            # MuJoCo runs its gravity-compensation pass only when some body had a non-zero gravcomp at
            # compile time; the excitations set the real values on the compiled model.
            if body is not spec.worldbody and body.gravcomp == 0.0:
                body.gravcomp = 1e-12
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.joint_names = tuple(robot_joint_names(self.model))
        imus = [self.model.site(i).name for i in range(self.model.nsite)]
        imus = [s for s in imus if s.startswith("imu") and s[3:].isdigit()]
        self.imu_names = tuple(sorted(imus, key=lambda s: int(s[3:])))
        self.no_gravcomp: set[str] = set()
        self._index()
        self._home()
        mujoco.mj_forward(self.model, self.data)

    # ----------------------------------------------------------------- constructors
    @classmethod
    def from_catalog(cls, name: str, *, rate: float = 100.0) -> Robot:
        from simulators.catalog import build

        return cls(build(name), name=name, rate=rate)

    @classmethod
    def from_file(
        cls, path: str | os.PathLike[str], *, rate: float = 100.0, imus_per_link: int = 2, seed: int = 0
    ) -> Robot:
        """An MJCF/URDF model; instrumented with ``imus_per_link`` IMUs per body if it has none."""
        spec = load_spec(path)
        if not any(s.name.startswith("imu") for s in spec.sites):
            instrument(spec, per_link=imus_per_link, seed=seed)
        else:
            from simulators.builder import add_drive

            add_drive(spec)
        return cls(spec, name=os.path.splitext(os.path.basename(os.fspath(path)))[0], rate=rate)

    # ------------------------------------------------------------------------ indexing
    def _index(self) -> None:
        m = self.model
        self.substeps = max(1, math.ceil(1.0 / (self.rate * self.max_timestep) - 1e-9))
        m.opt.timestep = 1.0 / (self.rate * self.substeps)
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        jid = [m.joint(j).id for j in self.joint_names]
        self.qpos_adr = np.array([m.jnt_qposadr[j] for j in jid], dtype=np.intp)
        self.dof_adr = np.array([m.jnt_dofadr[j] for j in jid], dtype=np.intp)
        self.site_ids = np.array([m.site(s).id for s in self.imu_names], dtype=np.intp)
        self.site_body = m.site_bodyid[self.site_ids].astype(np.intp)
        self.site_root = m.body_rootid[self.site_body].astype(np.intp)
        # (IMU bodies, nv): 1 where the dof moves the body (it is on the body or one of its ancestors)
        bodies, self._site_body_row = np.unique(self.site_body, return_inverse=True)
        self._body_dofs = np.zeros((len(bodies), m.nv))
        for i, b in enumerate(bodies):
            while b > 0:
                self._body_dofs[i, m.dof_bodyid == b] = 1.0
                b = int(m.body_parentid[b])
        names = [m.actuator(i).name for i in range(m.nu)]

        def act(suffix: str) -> np.ndarray:
            return np.array(
                [names.index(f"{j}:{suffix}") if f"{j}:{suffix}" in names else -1 for j in self.joint_names],
                dtype=np.intp,
            )

        self.act_torque, self.act_pos, self.act_vel = act("torque"), act("pos"), act("vel")
        sensors = {m.sensor(i).name: i for i in range(m.nsensor)}

        def adr(imu: str, kind: str) -> list[int]:
            sid = sensors.get(f"{imu}:{kind}")
            if sid is None:
                raise ValueError(f"IMU site {imu!r} has no sensor named {imu}:{kind}")
            a = int(m.sensor_adr[sid])
            return [a, a + 1, a + 2]

        self.acc_adr = np.array([adr(i, "acc") for i in self.imu_names], dtype=np.intp).reshape(-1, 3)
        self.gyro_adr = np.array([adr(i, "gyro") for i in self.imu_names], dtype=np.intp).reshape(-1, 3)
        self._integrate = _integrator(m)

    def _home(self, margin: float = 0.1) -> None:
        # Start inside every joint's range: a limited joint whose zero lies outside (or on the edge of)
        # its range starts ``margin`` inside it.
        m, d = self.model, self.data
        for name, adr in zip(self.joint_names, self.qpos_adr, strict=True):
            j = m.joint(name).id
            if m.jnt_limited[j]:
                lo, hi = m.jnt_range[j]
                mg = min(margin, 0.25 * (hi - lo))
                d.qpos[adr] = np.clip(d.qpos[adr], lo + mg, hi - mg)

    def _site_accelerations(
        self, dqacc: np.ndarray, cdof: np.ndarray, com: np.ndarray, site_pos: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """World (linear, angular) accelerations (T, K, 3) the joint accelerations ``dqacc`` (T, nv)
        give each IMU site, from the recorded motion axes of the dofs ``cdof`` (T, nv, 6: MuJoCo's
        com-based [rotation, translation], the translation at the root's subtree centre of mass
        ``com`` (T, nbody, 3)): each site sums its body's ancestor dofs (one array copy per sample
        instead of a Jacobian per body), moved to the site, ``a + alpha x (p_site - c)``."""
        spatial = np.matmul(self._body_dofs, cdof * dqacc[:, :, None])[:, self._site_body_row]  # (T, K, 6)
        ang, lin = spatial[..., :3], spatial[..., 3:]
        centre = com[:, self.site_root]
        return lin + np.cross(ang, site_pos[:, self.site_ids] - centre), ang

    def recompile(self) -> None:
        """Recompile the edited spec, keeping the simulation state (time, positions, velocities)."""
        self.model, self.data = self.spec.recompile(self.model, self.data)
        self._index()
        mujoco.mj_forward(self.model, self.data)

    # ------------------------------------------------------------------------ observables
    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_imus(self) -> int:
        return len(self.imu_names)

    @property
    def time(self) -> float:
        return float(self.data.time)

    def q(self) -> np.ndarray:
        return self.data.qpos[self.qpos_adr].copy()

    def qd(self) -> np.ndarray:
        return self.data.qvel[self.dof_adr].copy()

    def truth(self) -> Topology:
        """Ground truth of the current model (damage applied): detached IMUs are left out of ``imus``."""
        parents, imus, _ = truth_from_model(self.model, self.joint_names, self.imu_names)
        return Topology(joint_parent=parents, imu_joint=imus, method="ground-truth")

    def truth_arrays(self) -> tuple[tuple[str, ...], tuple[str, ...], np.ndarray]:
        """The truth arrays of docs/design.md, 'Recording' ('' = base) plus a (K,) bool mask of detached IMUs.

        A detached IMU keeps the last robot joint above its tether in ``truth_imu_joint``: the mask says
        it no longer follows it.
        """
        parents, imus, detached = truth_from_model(self.model, self.joint_names, self.imu_names)
        jp = tuple(parents[j] or "" for j in self.joint_names)
        ij = []
        for imu in self.imu_names:
            if imu in detached:
                b = int(self.model.site_bodyid[self.model.site(imu).id])
                ij.append(_last_robot_joint_up(self.model, b, set(self.joint_names)) or "")
            else:
                ij.append(imus[imu] or "")
        mask = np.array([imu in detached for imu in self.imu_names], dtype=bool)
        return jp, tuple(ij), mask

    def warnings(self) -> dict[str, int]:
        """MuJoCo warning counters that are non-zero (instability, limits hit), by warning name."""
        out = {}
        for i, w in enumerate(self.data.warning):
            if w.number:
                out[mujoco.mjtWarning(i).name] = int(w.number)
        return out

    def body_names(self, subtree_of: str | None = None) -> list[str]:
        """Bodies (all, or ``subtree_of`` and everything under it)."""
        m = self.model
        if subtree_of is None:
            return [m.body(b).name for b in range(1, m.nbody)]
        root = m.body(subtree_of).id
        out = []
        for b in range(1, m.nbody):
            c = b
            while c not in (0, root):
                c = int(m.body_parentid[c])
            if c == root:
                out.append(m.body(b).name)
        return out

    def set_gravcomp(self, value: float) -> None:
        """Gravity compensation of every body except loose ones and those listed in ``no_gravcomp``."""
        m = self.model
        for b in range(1, m.nbody):
            name = m.body(b).name
            m.body_gravcomp[b] = 0.0 if (name.startswith(LOOSE_PREFIX) or name in self.no_gravcomp) else value

    # ------------------------------------------------------------------------ stepping
    def sample(self, ctrl: np.ndarray, *, poses: bool = False) -> Samples:
        """Run ``len(ctrl)`` samples, holding ``ctrl[i]`` (nu,) over sample interval i; return readings.

        Sample i is taken at the start of its interval (time, state, and the acceleration the physics
        then realises over its first timestep; the accelerometers and ``qdd`` agree with it), then the
        physics advances ``substeps`` timesteps. ``poses`` also returns the sensor rotations ``R`` and
        angular accelerations ``gyro_dot`` (else they are empty arrays).

        Why "realised": MuJoCo's sensors read the explicit acceleration of the forward pass, while the
        implicit integrator moves the state with the one implicit in the damping and the drives' gains.
        With the catalog's stiff drives the two differ by several % of the joint accelerations below
        5 Hz (up to 0.06 m/s² at a UR5e's wrist at 1 kHz), so the IMUs would disagree with the motion
        the encoders report: the accelerometers are corrected by what the difference does at each
        site, through the dofs' motion axes (to 0.0006 m/s² there).
        """
        m = self.model
        ctrl = np.asarray(ctrl, dtype=np.float64)
        if ctrl.ndim != 2 or ctrl.shape[1] != m.nu:
            raise ValueError(f"ctrl must have shape (T, {m.nu}), got {ctrl.shape}")
        raw = self._run(ctrl, poses)
        T = ctrl.shape[0]
        t = raw.t0 + np.arange(T) * (self.substeps * m.opt.timestep)
        K = len(self.site_ids)
        R = raw.xmat[:, self.site_ids].reshape(T, K, 3, 3)
        realised = raw.realised
        realised -= raw.qvel
        realised /= m.opt.timestep
        lin, ang = self._site_accelerations(realised - raw.qacc, raw.cdof, raw.com, raw.site_pos)
        acc = raw.sens[:, self.acc_adr] + np.matmul(lin[:, :, None, :], R)[:, :, 0]  # R^T lin per sample
        if poses:
            alpha = raw.cacc[:, self.site_body, :3] + ang  # type: ignore[index]
            gyro_dot = np.einsum("tkji,tkj->tki", R, alpha)
        else:
            R, gyro_dot = np.empty((T, K, 0, 0)), np.empty((T, K, 0))
        return Samples(
            t=t,
            q=raw.qpos[:, self.qpos_adr],
            qd=raw.qvel[:, self.dof_adr],
            qdd=realised[:, self.dof_adr],
            acc=acc,
            gyro=raw.sens[:, self.gyro_adr],
            gyro_dot=gyro_dot,
            R=R,
        )

    def _run(self, ctrl: np.ndarray, poses: bool) -> _Raw:
        """Step the physics through ``ctrl`` and keep MjData's state at every sampling instant."""
        m, d = self.model, self.data
        T = ctrl.shape[0]
        raw = _Raw.empty(m, T, poses, d.time)
        qpos, qvel, qacc, sens, xmat, cacc = raw.qpos, raw.qvel, raw.qacc, raw.sens, raw.xmat, raw.cacc
        site_pos, com, cdof, realised = raw.site_pos, raw.com, raw.cdof, raw.realised
        integrate, rest = self._integrate, self.substeps - 1
        forward, step = mujoco.mj_forward, mujoco.mj_step
        opt = m.opt
        on = int(opt.disableflags) & ~int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        off = on | int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        # sensors only at the sampling instants: evaluating them at every timestep costs more than
        # the physics of a small robot (with one step per sample they simply stay on)
        opt.disableflags = on
        # views into MjData, bound once (each attribute access builds a new array object)
        d_ctrl, d_qpos, d_qvel, d_qacc, d_sens, d_xmat, d_cacc, d_sxpos, d_com, d_cdof = (
            d.ctrl,
            d.qpos,
            d.qvel,
            d.qacc,
            d.sensordata,
            d.site_xmat,
            d.cacc,
            d.site_xpos,
            d.subtree_com,
            d.cdof,
        )
        try:
            for i in range(T):
                d_ctrl[:] = ctrl[i]
                forward(m, d)
                qpos[i] = d_qpos
                qvel[i] = d_qvel
                qacc[i] = d_qacc  # before integrating: the qacc the accelerometers were computed with
                sens[i] = d_sens
                xmat[i] = d_xmat
                if poses:
                    cacc[i] = d_cacc  # type: ignore[index]
                site_pos[i] = d_sxpos
                com[i] = d_com
                cdof[i] = d_cdof
                integrate(m, d)
                realised[i] = d_qvel  # the velocity one timestep on: differenced below
                if rest:
                    opt.disableflags = off
                    step(m, d, nstep=rest)
                    opt.disableflags = on
        finally:
            opt.disableflags = off
        return raw


@dataclass(frozen=True)
class _Raw:
    """MjData's state at each sampling instant of one :meth:`Robot.sample` (``cacc`` only with poses)."""

    t0: float
    qpos: np.ndarray
    qvel: np.ndarray
    qacc: np.ndarray
    sens: np.ndarray
    xmat: np.ndarray
    cacc: np.ndarray | None
    site_pos: np.ndarray
    com: np.ndarray
    cdof: np.ndarray
    realised: np.ndarray

    @classmethod
    def empty(cls, m: mujoco.MjModel, T: int, poses: bool, t0: float) -> _Raw:
        return cls(
            t0=t0,
            qpos=np.empty((T, m.nq)),
            qvel=np.empty((T, m.nv)),
            qacc=np.empty((T, m.nv)),
            sens=np.empty((T, m.nsensordata)),
            xmat=np.empty((T, m.nsite, 9)),
            cacc=np.empty((T, m.nbody, 6)) if poses else None,
            site_pos=np.empty((T, m.nsite, 3)),
            com=np.empty((T, m.nbody, 3)),
            cdof=np.empty((T, m.nv, 6)),
            realised=np.empty((T, m.nv)),
        )


def _last_robot_joint_up(model: mujoco.MjModel, body: int, robot: set[str]) -> str | None:
    b = body
    while b != 0:
        js = [
            model.joint(j).name
            for j in range(model.njnt)
            if model.jnt_bodyid[j] == b and model.joint(j).name in robot
        ]
        if js:
            return js[-1]
        b = int(model.body_parentid[b])
    return None
