"""The walk down the tree: every IMU fitted parents first, in the frame of its parent link's reference IMU."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bodyschema.diff import undetermined_here
from bodyschema.kinematics.acc_frame import fuse, root_axis_acc
from bodyschema.kinematics.axis import AxisFit, GyroReading, axis_fit, gyro_reading, span_axes
from bodyschema.kinematics.lever_arm import ChildInputs, LeverFit, lever_child, lever_root
from bodyschema.kinematics.results import (
    ImuKinematics,
    JointKinematics,
    Kinematics,
    KinematicsOptions,
    SameLink,
)
from bodyschema.kinematics.same_link import same_link_fit, vec_text
from bodyschema.kinematics.signals import Signals, prepare_signals
from bodyschema.recording import Recording
from bodyschema.rigid_motion import project_rotation, rotation_about
from bodyschema.timing import timed_view
from bodyschema.topology import Topology

__all__ = [
    "estimate_kinematics",
]


def _order(topo: Topology) -> list[str]:
    """Joints parents first."""
    out: list[str] = []
    seen: set[str | None] = {None}
    todo = list(topo.joint_parent)
    while todo:
        ready = [j for j in todo if topo.joint_parent[j] in seen]
        if not ready:
            out.extend(todo)
            break
        out.extend(ready)
        seen.update(ready)
        todo = [j for j in todo if j not in seen]
    return out


@dataclass
class _Walk:
    """What the walk down the tree has found so far (joints are visited parents first)."""

    sig: Signals
    opts: KinematicsOptions
    topo: Topology
    on_joint: dict[str | None, list[str]]
    qd_rms: np.ndarray
    imus: dict[str, ImuKinematics] = field(default_factory=dict)
    omega: dict[str, np.ndarray] = field(default_factory=dict)  # each fitted IMU's link, own frame
    force: dict[str, np.ndarray] = field(default_factory=dict)  # each fitted IMU's modelled specific force
    ref: dict[str, str] = field(default_factory=dict)  # joint -> the IMU whose frame is its link's
    same: dict[str, SameLink] = field(default_factory=dict)  # other IMUs on a link against its ref

    @property
    def kidx(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.sig.rec.imu_names)}


def _with_timing(rec: Recording, topology: Topology | None) -> Topology:
    """The given tree (or the fast estimator's) with the IMU-to-encoder timing a multi-rate ``rec`` needs."""
    if topology is not None and (rec.t_q is None or topology.timing):
        return topology
    from dataclasses import replace

    from bodyschema.estimate import estimate_topology

    learned = estimate_topology(rec, method="fast")
    return learned if topology is None else replace(topology, timing=dict(learned.timing))


def _fit_link(w: _Walk, jn: str, j: int) -> None:
    """Fit every IMU on joint ``jn``'s link, pick the link's reference IMU, relate the others to it."""
    pj = w.topo.joint_parent.get(jn)
    parent = None if pj is None else w.ref.get(pj)
    kids, kidx = w.on_joint.get(jn, []), w.kidx
    for imu in kids:
        why_open = undetermined_here(w.topo, [f"imu:{imu}", f"joint:{jn}"])
        if why_open:
            w.imus[imu] = ImuKinematics(imu=imu, joint=jn, reason=why_open)
        elif w.qd_rms[j] < w.opts.min_qd_rms:
            why = f"joint {jn} hardly moved ({w.qd_rms[j]:.3g} rad/s RMS)"
            w.imus[imu] = ImuKinematics(imu=imu, joint=jn, reason=why)
        elif pj is not None and parent is None:
            w.imus[imu] = ImuKinematics(imu=imu, joint=jn, reason=f"no fitted IMU on the link of {pj}")
        else:
            w.imus[imu], w.omega[imu], w.force[imu] = _one_imu(
                w.sig, w.opts, j, jn, kidx[imu], imu, parent, kidx, w.omega, w.force
            )
    fitted = [k for k in kids if w.imus[k].axis is not None]
    if not fitted:
        return
    # the first whose axis converged: the same IMU from one recording to the next (a lever arm's
    # convergence varies with the motion more), so the joints below are read in the same frame
    w.ref[jn] = next((k for k in fitted if w.imus[k].axis_converged), fitted[0])
    for b in kids:
        if b != w.ref[jn]:
            sl = same_link_fit(
                w.sig, kidx[w.ref[jn]], kidx[b], w.sig.rec.imu_names, w.omega[w.ref[jn]], w.opts
            )
            if sl is not None:
                w.same[b] = sl


def _joint_entry(w: _Walk, jn: str, j: int) -> JointKinematics:
    """Joint ``jn``'s axis in every IMU frame of its parent link (through the same-link rotations)."""
    pj = w.topo.joint_parent.get(jn)
    parent = None if pj is None else w.ref.get(pj)
    in_parent: dict[str, np.ndarray] = {}
    open_: list[str] = []
    axis_p = w.imus[w.ref[jn]].axis_in_parent if jn in w.ref else None
    if parent is not None and axis_p is not None:
        in_parent[parent] = axis_p
        ref = w.imus[w.ref[jn]]
        if ref.undetermined:
            open_.append(
                f"the axis in {parent}'s frame, turned about {parent}'s link axis: std "
                f"{ref.turn_about_parent_std_deg:.2f} deg, from {ref.imu}'s rotation_from_parent "
                "(see its own)"
            )
        left_out = []
        for b in w.on_joint.get(pj, []):
            if b in w.same and w.same[b].a == parent:
                if w.same[b].rank >= 2:
                    in_parent[b] = w.same[b].rotation.T @ axis_p
                else:
                    left_out.append(b)
        if left_out:
            open_.append(
                f"the axis in the frames of {', '.join(left_out)}: left out, their rotations from {parent} "
                "are open about the one axis their link turned about (see same_link)"
            )
    q = w.sig.rec.q[:, j]  # type: ignore[index]
    kids = w.on_joint.get(jn, [])
    return JointKinematics(
        joint=jn,
        parent=pj,
        imus=tuple(kids),
        ref_imu=w.ref.get(jn),
        axis_in_parent=in_parent,
        q_range=(float(np.min(q)), float(np.max(q))),
        converged=any(w.imus[k].converged for k in kids),
        undetermined=tuple(open_),
    )


def estimate_kinematics(
    rec: Recording, topology: Topology | None = None, options: KinematicsOptions | None = None
) -> Kinematics:
    """Joint axes, IMU lever arms and same-link rotations of ``rec`` (model in the module docstring).

    ``topology`` is the learned or given tree; without one the fast estimator learns it. A multi-rate
    recording, or a single-clock one without measured velocities (read as ``t_q = t``,
    :func:`bodyschema.timing.timed_view`), is aligned with the lag in ``topology.timing`` (the fast
    estimator's; a topology without timing gets it from a fast fit of ``rec``). An IMU the tree that
    fits does not place (:func:`bodyschema.diff.open_parts`) is not fitted: its reason says so.
    """
    opts = options or KinematicsOptions()
    rec = timed_view(rec)  # positions only, on one clock: the timed path, as the fast estimator reads it
    topo = _with_timing(rec, topology)
    sig = prepare_signals(rec, topo, opts)
    al = sig.rec
    on_joint: dict[str | None, list[str]] = {}
    for imu in al.imu_names:
        if imu in topo.imu_joint:
            on_joint.setdefault(topo.imu_joint[imu], []).append(imu)
    qd_rms = np.sqrt(np.mean(sig.band_limit(al.qd) ** 2, axis=0))  # type: ignore[arg-type]
    w = _Walk(sig=sig, opts=opts, topo=topo, on_joint=on_joint, qd_rms=qd_rms)
    for imu in on_joint.get(None, []):
        why = undetermined_here(topo, [f"imu:{imu}"]) or "on the base: no joint moves it"
        w.imus[imu] = ImuKinematics(imu=imu, joint=None, reason=why)
    jidx = {n: i for i, n in enumerate(al.joint_names)}
    joints: dict[str, JointKinematics] = {}
    for jn in _order(topo):
        if jn in jidx:
            _fit_link(w, jn, jidx[jn])
            joints[jn] = _joint_entry(w, jn, jidx[jn])
    lag = float(topo.timing.get("lag_ms", 0.0)) if rec.t_q is not None else 0.0
    return Kinematics(
        imus={k: w.imus[k] for k in al.imu_names if k in w.imus},
        joints=joints,
        same_link=tuple(w.same.values()),
        band_hz=sig.band,
        lag_ms=lag,
        samples=al.n_samples,
        topology=topo,
    )


@dataclass(frozen=True)
class _Found:
    """One IMU's fits before they are judged (:func:`_one_imu`)."""

    fit: AxisFit
    axis: np.ndarray
    axis_std: float
    om: np.ndarray
    gyro: GyroReading
    lever: LeverFit
    R0: np.ndarray | None = None
    d: np.ndarray | None = None
    p_axis: np.ndarray | None = None


def _root_imu(sig: Signals, opts: KinematicsOptions, j: int, c: int) -> _Found:
    """An IMU under a root joint on the fixed base: the axis from its gyro, leaned by its accelerometer."""
    qd = sig.rec.qd[:, j]  # type: ignore[index]
    fit = axis_fit(sig, j, c, None)
    axis, axis_std = fit.axis, fit.std_deg
    om = fit.axis * qd[:, None]
    gyro = gyro_reading(sig, j, c, None)
    lever = lever_root(sig, j, c, fit.axis, om)
    if opts.accelerometer_frame:
        noise_var = math.radians(fit.std_deg) ** 2 / 2.0
        gain_std = opts.acc_scale_error / math.sqrt(3.0)
        acc = root_axis_acc(sig, j, c, fit.axis, lever.turning, gain_std)  # type: ignore[arg-type]
        axis, axis_std = fuse(fit.axis, noise_var, acc, slice(0, 2), opts)
        om = axis * qd[:, None]
        lever = lever_root(sig, j, c, axis, om)
    return _Found(fit=fit, axis=axis, axis_std=axis_std, om=om, gyro=gyro, lever=lever)


def _child_imu(
    sig: Signals, opts: KinematicsOptions, j: int, c: int, p: int, omega_p: np.ndarray, force_p: np.ndarray
) -> _Found:
    """An IMU under a joint whose parent link has the fitted IMU ``p`` (rebuilt ``omega_p``, modelled
    specific force ``force_p``)."""
    q, qd = sig.rec.q[:, j], sig.rec.qd[:, j]  # type: ignore[index]
    fit = axis_fit(sig, j, c, omega_p)
    u = fit.axis
    # R0 on the span of the parent's motion (all that ω_c needs), from the gyro
    Rg = project_rotation(fit.H)  # type: ignore[arg-type]
    om = np.einsum("ij,tj->ti", Rg, omega_p)
    om = np.einsum("tij,tj->ti", rotation_about(u, -q), om) + u * qd[:, None]
    rank, p_axis = span_axes(fit.span)  # type: ignore[arg-type]
    noise_var = math.radians(fit.std_deg) ** 2 / 2.0
    lever = lever_child(sig, j, c, p, u, ChildInputs(om, omega_p, Rg, rank, p_axis, opts, noise_var, force_p))
    R0, d = lever.M0, lever.d
    gyro = gyro_reading(sig, j, c, p)
    axis, axis_std = u, fit.std_deg
    if opts.accelerometer_frame:
        # the child's frame is now its accelerometer's: rebuild ω_c in it for the joints below
        axis, axis_std = lever.axis, lever.axis_std_deg  # type: ignore[assignment]
        om = np.einsum("ij,tj->ti", R0, omega_p)  # type: ignore[arg-type]
        om = np.einsum("tij,tj->ti", rotation_about(axis, -q), om) + axis * qd[:, None]
    return _Found(fit, axis, axis_std, om, gyro, lever, R0=R0, d=d, p_axis=p_axis)


def _one_imu(
    sig: Signals,
    opts: KinematicsOptions,
    j: int,
    jn: str,
    c: int,
    imu: str,
    parent: str | None,
    kidx: dict[str, int],
    omega: dict[str, np.ndarray],
    force: dict[str, np.ndarray],
) -> tuple[ImuKinematics, np.ndarray, np.ndarray]:
    """Axis, lever arm, the rebuilt angular velocity of one IMU's link and its modelled specific force,
    and the joint as the gyros alone read it (:func:`~bodyschema.kinematics.axis.gyro_reading`);
    ``parent``: the reference IMU of the parent link (None: a root joint on the fixed base); ``force``:
    the modelled specific forces of the IMUs fitted so far (:func:`lever_child` reads its parent's)."""
    if parent is None:
        x = _root_imu(sig, opts, j, c)
    else:
        x = _child_imu(sig, opts, j, c, kidx[parent], omega[parent], force[parent])
    fit, lever, gyro, R0 = x.fit, x.lever, x.gyro, x.R0
    open_: tuple[str, ...] = ()
    if lever.turn_std_deg > opts.max_axis_std_deg:  # a child of a one-axis parent (NaN otherwise)
        up = sig.rec.acc[:, kidx[parent]].mean(axis=0)  # type: ignore[index]
        open_ = (_open_turn(up, x.p_axis, parent, lever.turn_std_deg, opts),)  # type: ignore[arg-type]
    lo, hi = opts.gain_range
    why = []
    if fit.std_deg > opts.max_axis_std_deg:
        why.append(f"gyro axis std {fit.std_deg:.2f} deg > {opts.max_axis_std_deg:g}")
    if not lo <= fit.gain <= hi:
        why.append(f"gyro gain {fit.gain:.2f} outside {lo:g}..{hi:g}")
    axis_converged = not why
    if lever.std_m > opts.max_lever_std_m:
        why.append(f"lever-arm std {lever.std_m * 1e3:.1f} mm > {opts.max_lever_std_m * 1e3:g}")
    return (
        ImuKinematics(
            imu=imu,
            joint=jn,
            parent_imu=parent,
            axis=x.axis,
            lever_arm=lever.r,
            axis_std_deg=x.axis_std,
            lever_arm_std_m=lever.std_m,
            gain=fit.gain,
            rotation_from_parent=R0,
            axis_in_parent=None if R0 is None else R0.T @ x.axis,
            joint_origin_in_parent=x.d,
            up_at_zero=lever.up,
            converged=not why,
            axis_converged=axis_converged,
            reason="; ".join(why),
            gyro_axis=gyro.fit.axis,
            gyro_axis_std_deg=gyro.fit.std_deg,
            gyro_axis_in_parent=gyro.in_parent,
            gyro_parent_axis=gyro.parent_axis,
            gyro_axis_in_parent_std_deg=gyro.in_parent_std_deg,
            parent_rank=gyro.parent_rank,
            backlash_deg=gyro.fit.backlash_deg,
            backlash_std_deg=gyro.fit.backlash_std_deg,
            turn_about_parent_std_deg=lever.turn_std_deg,
            undetermined=open_,
        ),
        x.om,
        lever.force,  # type: ignore[return-value]
    )


def _open_turn(up: np.ndarray, axis: np.ndarray, parent: str, std: float, opts: KinematicsOptions) -> str:
    """What a child's turn about its one-axis parent's axis leaves open (module docstring), and the
    motion that fixes it; ``up`` is the parent's mean specific force and ``axis`` its axis, both in
    the parent's frame."""
    tilt = math.degrees(math.acos(min(abs(float(up @ axis)) / max(float(np.linalg.norm(up)), 1e-12), 1.0)))
    return (
        f"the turn about {parent}'s link axis ({vec_text(axis)} in {parent}'s frame, {tilt:.0f} deg from "
        f"vertical) of rotation_from_parent and joint_origin_in_parent: std {std:.2f} deg > "
        f"{opts.max_axis_std_deg:g}; the joint's position about that axis trades with it and only gravity "
        "across the axis tells it; a recording with that axis further from vertical fixes it, or the joint's "
        "position from a drawing"
    )
