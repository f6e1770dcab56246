"""A floating-base robot's URDF, its recorded encoders and contacts, and what its base IMU should read.

The glue around :mod:`bodyschema.floating_base` and :mod:`bodyschema.contacts`: reads the URDF
(``yourdfpy`` for the joints; the IMU mount from a robot-level ``<sensor>`` element, an iDynTree
extension ``yourdfpy`` skips, or else a link named like an IMU), builds one serial chain from the IMU
frame to every foot, finds the contacts from the recording's foot forces and predicts the IMU two
ways where the recording allows:

* ``"encoders"``: the rigid model driven by the encoders over the stance feet (leg odometry);
* ``"mocap"``: the base pose of motion capture (``extra['base_pos']``, ``extra['base_rot']``
  roll-pitch-yaw), carried to the IMU by the URDF mount: an independent simulation of the same IMU.

Each prediction then goes through the held-out effect selection of :mod:`bodyschema.discrepancy`
(:func:`robot_sim2real`). What a recording lacks (no forces: no contacts; no base pose: no mocap) is
said in ``could_not``, never guessed.
"""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bodyschema.contacts import (
    change_mask,
    contact_weights,
    force_contacts,
    kinematic_contact,
    ramp_time,
    transition_weights,
)
from bodyschema.floating_base import (
    SerialChain,
    band_cutoff,
    body_reference,
    chain_frames,
    chain_motion,
    derivative,
    flat_foot_gravity,
    foot_plane_gravity,
    quantization_floor,
    stance_twist,
    tilt_filter,
)
from bodyschema.floating_effects import forward_select, linear_effect, transition_ratio
from bodyschema.recording import Recording
from bodyschema.rigid_motion import lowpass, reference_motion
from sim2real.robot_agreement import agreement, closure, prediction_lag, prediction_rotation

__all__ = [
    "RobotModel",
    "RobotOptions",
    "predict_encoders",
    "predict_mocap",
    "read_robot",
    "robot_sim2real",
]


@dataclass(frozen=True)
class RobotOptions:
    """Settings of the robot analysis (the IMU analysis's own are passed through)."""

    #: Common low-pass of prediction and readings, Hz (None: where encoder quantization puts
    #: ``quantization_tol`` on the predicted specific force, at most 10 Hz).
    cutoff: float | None = None
    #: Specific-force noise (m/s², 1 % of g) encoder quantization may put on the prediction.
    quantization_tol: float = 0.1
    #: False-contact rate per sample accepted by the force threshold.
    p_false: float = 1e-3
    #: Time constant of the tilt carried between plane measurements (point feet), s.
    tilt_tau: float = 0.5
    #: Held-out time blocks, family level and least gain of the effect selection.
    n_blocks: int = 8
    alpha: float = 0.01
    min_gain: float = 0.005
    #: Half-width of the window around contact changes compared with the rest (lift-off, roll), s.
    change_half_s: float = 0.05
    #: A foot's stance weight ramps from 0 at its own contact change to full over this many seconds
    #: (0: the rigid model, every foot down at full weight; set from the forces' ramp time when the
    #: rigid model's residual shows the contact changes).
    settle_s: float = 0.0


@dataclass(frozen=True)
class RobotModel:
    """What the analysis needs of a URDF: the IMU frame in the root link, every foot as a chain from
    the IMU frame, flat or point feet, the total mass."""

    name: str
    imu_source: str
    imu_in_root: np.ndarray
    feet: dict[str, SerialChain]
    flat: bool
    mass: float
    joint_names: tuple[str, ...]
    unmatched: list[str] = field(default_factory=list)


def _origin(el: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if el is None:
        return T
    xyz = [float(x) for x in el.get("xyz", "0 0 0").split()]
    rpy = [float(x) for x in el.get("rpy", "0 0 0").split()]
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF: fixed axes x, y, z
    T[:3, 3] = xyz
    return T


def _imu_mounts(path: Path, links: dict[str, object]) -> list[tuple[str, str, np.ndarray]]:
    """Candidate (parent link, where it came from, IMU frame in that link): every robot-level
    accelerometer or IMU ``<sensor>``, then every link named ``*imu*`` (its own frame)."""
    root = ET.parse(path).getroot()
    out = [
        (s.find("parent").get("link"), f"sensor {s.get('name')}", _origin(s.find("origin")))
        for s in root.findall("sensor")
        if s.get("type") in ("accelerometer", "imu") and s.find("parent") is not None
    ]
    out.sort(key=lambda m: "imu" not in m[1].lower())  # an IMU before other accelerometers
    out += [(n, f"link {n}", np.eye(4)) for n in links if re.search(r"imu", n, re.I)]
    return out


def _feet(link_names: list[str]) -> tuple[list[str], bool]:
    """Flat feet (``*_sole`` links) when the model has them, else point feet (``*_foot``)."""
    soles = [n for n in link_names if n.endswith("_sole")]
    if soles:
        return soles, True
    feet = [n for n in link_names if n.endswith("_foot")]
    if not feet:
        raise ValueError("the model has no *_sole or *_foot links: no feet to stand on")
    return feet, False


def _joint_column(urdf_joint: str, names: tuple[str, ...]) -> int | None:
    for c, n in enumerate(names):
        if urdf_joint in (n, f"{n}_joint"):
            return c
    return None


def read_robot(path: str | Path, joint_names: tuple[str, ...]) -> RobotModel:
    """The robot of URDF ``path`` for a recording with ``joint_names``."""
    import yourdfpy

    path = Path(path)
    u = yourdfpy.URDF.load(
        str(path), load_meshes=False, build_scene_graph=False, build_collision_scene_graph=False
    )
    by_child = {j.child: j for j in u.robot.joints}
    links = {lk.name: lk for lk in u.robot.links}

    def to_root(link: str) -> list:
        out = []
        while link in by_child:
            out.append(by_child[link])
            link = by_child[link].parent
        return out[::-1]

    # The base IMU: the first candidate whose link only fixed joints tie to the root.
    mounts = [m for m in _imu_mounts(path, links) if all(j.type == "fixed" for j in to_root(m[0]))]
    if not mounts:
        raise ValueError(f"{path.name}: no IMU sensor element or *imu* link fixed to the base")
    imu_link, source, T_link_imu = mounts[0]
    T_root_imu = np.eye(4)
    for j in to_root(imu_link):
        T_root_imu = T_root_imu @ j.origin
    T_root_imu = T_root_imu @ T_link_imu
    feet, flat = _feet(list(links))
    chains, unmatched = {}, []
    for foot in feet:
        origins, axes, cols, pending = [], [], [], np.linalg.inv(T_root_imu)
        for j in to_root(foot):
            pending = pending @ j.origin
            if j.type == "fixed":
                continue
            c = _joint_column(j.name, joint_names)
            if c is None or j.type not in ("revolute", "continuous"):
                unmatched.append(j.name)
                continue  # held at 0: its chain is then approximate, and said so
            origins.append(pending)
            axes.append(np.asarray(j.axis, float) / np.linalg.norm(j.axis))
            cols.append(c)
            pending = np.eye(4)
        chains[foot] = SerialChain(
            np.array(origins).reshape(-1, 4, 4), np.array(axes).reshape(-1, 3), tuple(cols), pending
        )
    if not any(c.columns for c in chains.values()):
        raise ValueError(
            f"{path.name}: none of the legs' joints ({sorted(set(unmatched))[:4]}...) is in the recording"
        )
    mass = sum(lk.inertial.mass for lk in u.robot.links if lk.inertial is not None and lk.inertial.mass)
    return RobotModel(
        u.robot.name,
        source,
        T_root_imu,
        chains,
        flat,
        float(mass),
        tuple(joint_names),
        sorted(set(unmatched)),
    )


def _uniform(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """A uniform grid at the recording's median step over its span, and the indices it lands on."""
    dt = float(np.median(np.diff(rec.t)))
    t = np.arange(rec.t[0], rec.t[-1], dt)
    return t, np.searchsorted(rec.t, t)


def _interp(t_new: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    flat = x.reshape(x.shape[0], -1)
    out = np.stack([np.interp(t_new, t, flat[:, i]) for i in range(flat.shape[1])], axis=1)
    return out.reshape((t_new.size, *x.shape[1:]))


def _foot_forces(rec: Recording, feet: list[str]) -> tuple[np.ndarray | None, str]:
    """(T, F) force per foot in ``feet`` order from the recording's extras, matched by name prefix
    (``lf_force_z`` -> ``l_sole``; ``foot_force`` columns ``FR_Force`` ... -> ``FR_foot``)."""
    prefix = [f.split("_")[0].lower() for f in feet]
    ex = rec.extra
    if all(f"{p}f_force_z" in ex for p in prefix):
        return np.stack([np.asarray(ex[f"{p}f_force_z"], float) for p in prefix], axis=1), "*f_force_z"
    if "foot_force" in ex:
        report = json.loads(str(ex["import_report"])) if "import_report" in ex else {}
        cols = report.get("streams", {}).get("extra:foot_force", {}).get("source")
        if cols and len(cols) == ex["foot_force"].shape[1]:
            order = [[c.split("_")[0].lower() for c in cols].index(p) for p in prefix]
            return np.asarray(ex["foot_force"], float)[:, order], "foot_force"
    return None, ""


def _quantum(rec: Recording) -> float | None:
    """The encoders' quantum from the import report (None when it did not resolve one)."""
    if "import_report" not in rec.extra:
        return None
    enc = json.loads(str(rec.extra["import_report"])).get("encoders", {})
    qs = [
        v["quantum_rad"] if v.get("matches_power_of_two") else v.get("resolution_rad")
        for v in enc.values()
        if isinstance(v, dict)
    ]
    qs = [q for q in qs if q]
    return float(np.median(qs)) if qs else None


@dataclass
class Prediction:
    """One prediction of the IMU on the uniform grid: the reference motion, the readings resampled
    beside it, the usable samples and what was said about how it was made."""

    name: str
    ref: object
    gyro: np.ndarray
    acc: np.ndarray
    valid: np.ndarray
    notes: dict[str, object] = field(default_factory=dict)
    #: Gyro regressors (T, 3, k) of the robot's own effects on the same grid, by effect name.
    regressors: dict[str, np.ndarray] = field(default_factory=dict)
    #: Grid samples within a window of a contact change.
    near_change: np.ndarray | None = None


def _stance(rec: Recording, model: RobotModel, t: np.ndarray, opts: RobotOptions, could_not: list[str]):
    """(weights (T, F), contacts JSON, down (T, F)) on the grid ``t`` from the foot forces."""
    names = list(model.feet)
    forces, source = _foot_forces(rec, names)
    if forces is None:
        could_not.append(
            "contacts from forces: the recording has no foot forces (no prediction from encoders)"
        )
        return None, None, None, None
    f = _interp(t, rec.t, forces)
    rate = 1.0 / float(np.median(np.diff(t)))
    c = force_contacts(f, rate, opts.p_false)
    info = {"source": source, "feet": names, **c.to_json()}
    if model.flat and "lf_force_z" in rec.extra:
        info["threshold_of_weight"] = [float(x / (model.mass * 9.81)) for x in c.threshold]
    w = contact_weights(f, c)
    if opts.settle_s > 0:
        w = w * transition_weights(c.down, rate, opts.settle_s)
        tot = w.sum(axis=1, keepdims=True)
        w = np.divide(w, tot, out=np.zeros_like(w), where=tot > 0)
    info["settle_s"] = ramp_time(f, c, rate)
    return w, info, c.down, f


def predict_encoders(
    rec: Recording, model: RobotModel, opts: RobotOptions, could_not: list[str], k: int = 0
) -> Prediction | None:
    """The IMU predicted by the rigid model over the stance feet (None when no contacts are known)."""
    t, _ = _uniform(rec)
    weights, contacts, down, forces = _stance(rec, model, t, opts, could_not)
    if weights is None:
        return None
    rate = 1.0 / float(np.median(np.diff(t)))
    q = lowpass(_interp(t, rec.t if rec.t_q is None else rec.t_q, rec.q), rate, opts.cutoff)
    qd = derivative(t, q)
    feet = [chain_motion(ch, q, qd, model.flat) for ch in model.feet.values()]
    gyro = _interp(t, rec.t, rec.gyro[:, k])
    acc = _interp(t, rec.t, rec.acc[:, k])
    fill = None if model.flat else lowpass(gyro, rate, opts.cutoff)
    w, v, seen = stance_twist(feet, weights, fill)
    g = np.asarray(rec.gravity, float)
    if model.flat:
        g_body = flat_foot_gravity(feet, weights, g)
        tilt = "flat stance feet taken level"
    else:
        plane = foot_plane_gravity(np.stack([f.p for f in feet], axis=1), down, g)
        g_body = tilt_filter(t, w, plane, opts.tilt_tau)
        tilt = f"plane of >= 3 stance feet ({np.isfinite(plane[:, 0]).mean():.1%} of samples), carried by w"
    any_down = down.any(axis=1)
    g_body = np.where(np.isfinite(g_body), g_body, np.nan)
    if np.isnan(g_body).any():
        g_body = _fill_nan(g_body)
    ref = body_reference(t, w, v, g_body, g, opts.cutoff)
    notes = {
        "contacts": contacts,
        "tilt": tilt,
        "gyro_predicted_fraction": seen.mean(axis=0).tolist(),
        "gyro_fully_predicted": float(seen.all(axis=1).mean()),
        "gyro_fill": None if model.flat else "measured gyro, only about axes the stance feet leave free",
        "samples_no_foot_down": float(1.0 - any_down.mean()),
    }
    legs = max(len(c.columns) for c in model.feet.values())
    notes["kinematic_contacts"] = _kinematic_contacts(rec, feet, legs, w, v, down, rate, opts)
    if model.flat:
        frames = [chain_frames(ch, q) for ch in model.feet.values()]
        regs = _compliance(model, frames, weights, forces, g_body, t, opts, could_not)
        regs.update(_sole_compliance(rec, model, frames, weights, g_body, t, opts, could_not))
    else:
        regs = {}
        could_not.append("leg_compliance: tested for flat feet only (a point foot's flex moves no rotation)")
    near = change_mask(down, rate, opts.change_half_s)
    return Prediction("encoders", ref, gyro, acc, any_down, notes, regs, near)


def _kinematic_contacts(
    rec: Recording,
    feet: list,
    legs: int,
    w: np.ndarray,
    v: np.ndarray,
    down: np.ndarray,
    rate: float,
    opts: RobotOptions,
) -> dict[str, object]:
    """Contacts from the kinematics alone, beside the forces': each foot's world speed under the
    base twist (``v + w x p + dp``), its median on force-down and force-up samples, and the share of
    samples where "speed within the encoders' noise" (:func:`~bodyschema.contacts.kinematic_contact`)
    agrees with the forces. The noise: the quantization floor of two legs' rates through the foot's
    lever, per axis."""
    speed = np.stack([np.linalg.norm(v + np.cross(w, f.p) + f.v, axis=1) for f in feet], axis=1)
    quantum = _quantum(rec)
    out: dict[str, object] = {
        "median_speed_down": [float(np.median(speed[down[:, j], j])) for j in range(len(feet))],
        "median_speed_up": [
            float(np.median(speed[~down[:, j], j])) if (~down[:, j]).any() else None for j in range(len(feet))
        ],
    }
    if quantum is not None:
        lever = float(np.median([np.median(np.linalg.norm(f.p, axis=1)) for f in feet]))
        joints = max(1, rec.q.shape[1] // max(len(feet), 1))
        sigma = (
            quantization_floor(quantum, rate, opts.cutoff, 1.0, 2 * joints)["gyro_std"] * lever / np.sqrt(3.0)
        )
        kin = kinematic_contact(speed, sigma, opts.p_false)
        out.update(speed_noise_per_axis=float(sigma), agree_with_forces=float(np.mean(kin == down)))
    return out


def _with_rates(t: np.ndarray, x: np.ndarray, cutoff: float | None) -> tuple[np.ndarray, ...]:
    """``x`` (T, ...) low-passed like the readings, and its first and second time derivatives."""
    rate = 1.0 / float(np.median(np.diff(t)))
    x = lowpass(x.reshape(t.size, -1), rate, cutoff).reshape(x.shape)
    dx = derivative(t, x)
    return x, dx, derivative(t, dx)


def _flex(
    w: np.ndarray, load: list[np.ndarray], a: np.ndarray, p: np.ndarray, g_body: np.ndarray
) -> np.ndarray:
    """(T, 6) gyro then specific force of a flex by ``c x`` (per unit ``c``) about the axis ``a``
    (T, 3) through ``p`` (T, 3) of a stance foot weighted ``w`` (T, 1); ``load`` is ``x`` and its two
    rates, each (T, 1). The base turns by ``-c x`` about ``a`` (:mod:`bodyschema.floating_effects`)."""
    x, dx, ddx = load
    gyro = -w * dx * a
    acc = w * (ddx * np.cross(a, p) - x * np.cross(a, g_body))
    return np.concatenate([gyro, acc], axis=1)


def _compliance(
    model: RobotModel,
    frames: list[tuple[np.ndarray, ...]],
    weights: np.ndarray,
    forces: np.ndarray,
    g_body: np.ndarray,
    t: np.ndarray,
    opts: RobotOptions,
    could_not: list[str],
) -> dict[str, np.ndarray]:
    """Leg-compliance regressors, one candidate per joint of the legs (``compliance[hip_roll]``:
    (T, 6, legs), gyro then specific force, one column per leg; see
    :mod:`bodyschema.floating_effects`; ``frames``: each foot's :func:`chain_frames`). Joints are
    matched across legs by their name without the leg's prefix (``l_hip_roll``, ``r_hip_roll`` ->
    ``hip_roll``)."""
    F = _with_rates(t, forces, opts.cutoff)
    cand: dict[str, list[np.ndarray]] = {}
    for f, (ch, (_, _, axes, points)) in enumerate(zip(model.feet.values(), frames, strict=True)):
        for i, c in enumerate(ch.columns):
            flex = _flex(weights[:, f, None], [x[:, f, None] for x in F], axes[:, i], points[:, i], g_body)
            key = model.joint_names[c].split("_", 1)[-1]
            cand.setdefault(f"compliance[{key}]", []).append(flex)
    out = {k: np.stack(v, axis=2) for k, v in cand.items() if len(v) == len(model.feet)}
    if not out:
        could_not.append("leg_compliance: the legs share no joint names, so no per-joint compliance")
    return out


def _foot_wrenches(rec: Recording, feet: list[str], t: np.ndarray) -> np.ndarray | None:
    """(T, F, 6) each foot's contact wrench (force, then moment about the sole's origin, in the sole's
    frame) on the grid ``t``, from the extras ``lf_wrench``, ``rf_wrench`` (None when any is missing)."""
    keys = [f"{f.split('_')[0].lower()}f_wrench" for f in feet]
    if not all(k in rec.extra and np.shape(rec.extra[k])[1:] == (6,) for k in keys):
        return None
    return np.stack([_interp(t, rec.t, np.asarray(rec.extra[k], float)) for k in keys], axis=1)


def _sole_compliance(
    rec: Recording,
    model: RobotModel,
    frames: list[tuple[np.ndarray, ...]],
    weights: np.ndarray,
    g_body: np.ndarray,
    t: np.ndarray,
    opts: RobotOptions,
    could_not: list[str],
) -> dict[str, np.ndarray]:
    """Sole-compliance regressors, one candidate per axis of the sole (``compliance[sole_x]``: (T, 6,
    legs)): the foot turns on its sole and ankle by ``c M`` under the moment ``M`` of the ground's
    reaction about that axis, a joint at the sole's origin whose flex follows the moment rather than
    the vertical load (the same terms as :func:`_compliance`). Weight moving from heel to toe turns
    a stance foot the rigid model holds flat; rad/(N m)."""
    wrench = _foot_wrenches(rec, list(model.feet), t)
    if wrench is None:
        could_not.append("sole compliance: the recording has no foot wrenches (lf_wrench, rf_wrench)")
        return {}
    M = _with_rates(t, wrench[..., 3:], opts.cutoff)
    out: dict[str, list[np.ndarray]] = {}
    for f, (R_sole, p_sole, _, _) in enumerate(frames):
        for k, axis in enumerate("xyz"):
            flex = _flex(weights[:, f, None], [x[:, f, k, None] for x in M], R_sole[:, :, k], p_sole, g_body)
            out.setdefault(f"compliance[sole_{axis}]", []).append(flex)
    return {k: np.stack(v, axis=2) for k, v in out.items()}


def _inner(pred: Prediction) -> np.ndarray:
    """The prediction's usable samples less 0.25 s at either end (where the low-passes ring)."""
    m = round(0.25 / float(np.median(np.diff(pred.ref.t))))
    use = pred.valid.copy()
    use[:m], use[-m:] = False, False
    return use


def _rigid_residual(pred: Prediction, opts: RobotOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(residual (T, 6) measured - predicted, both low-passed alike; samples used; their 2 s blocks)."""
    from bodyschema.imu_effects import specific_force

    ref, t = pred.ref, pred.ref.t
    rate = 1.0 / float(np.median(np.diff(t)))
    meas = np.concatenate([lowpass(pred.gyro, rate, opts.cutoff), lowpass(pred.acc, rate, opts.cutoff)], 1)
    model = np.concatenate([ref.omega, specific_force(ref.R, ref.acc_world, ref.gravity)], 1)
    use = _inner(pred)
    block = np.floor((t - t[0]) / 2.0).astype(int)
    return meas - model, use, block


#: A joint's flex under the leg's vertical load, and a sole's under the ground reaction's moment.
_COMPLIANCE_UNIT = {False: "rad/N", True: "rad/(N m)"}


def _extend(pred: Prediction, opts: RobotOptions) -> list[dict[str, object]]:
    """Select the robot's own effects on the rigid model's residual (forward, held out over 2 s
    blocks, :func:`~bodyschema.floating_effects.forward_select`), fit the named ones together and
    put them into the prediction, before the IMU effects are selected."""
    if not pred.regressors:
        return []
    res, use, block = _rigid_residual(pred, opts)
    scale = np.sqrt(np.mean(res[use] ** 2, axis=0).reshape(2, 3).mean(axis=1)).repeat(3)
    cands = {k: X[use] / scale[None, :, None] for k, X in pred.regressors.items()}
    r = (res / scale)[use]
    named, rounds = forward_select(r, cands, block[use], opts.alpha, opts.min_gain)
    out: dict[str, object] = {
        "effect": "leg_compliance",
        "named": bool(named),
        "joints": named,
        "rounds": rounds,
    }
    if named:
        X = np.concatenate([cands[n] for n in named], axis=2)
        e = linear_effect("leg_compliance", r, X, block[use], opts.alpha, opts.min_gain)
        hb, ha = (np.asarray(e["held_out_energy"][k]) for k in ("before", "after"))
        legs = pred.regressors[named[0]].shape[2]
        out.update({k: e[k] for k in ("value", "std", "interval", "p_value", "gain", "blocks")})
        out.update(
            named=True,
            unit="rad/N",  # a sole's moment compliance (compliance[sole_*]): rad/(N m), in ``units``
            units=[_COMPLIANCE_UNIT[n.startswith("compliance[sole_")] for n in named for _ in range(legs)],
            columns=[f"{n}[leg {i}]" for n in named for i in range(legs)],
            channel="gyro and acc",
            channel_gain={
                "gyro": float(1 - ha[:3].sum() / hb[:3].sum()),
                "acc": float(1 - ha[3:].sum() / hb[3:].sum()),
            },
        )
        full = np.concatenate([pred.regressors[n] for n in named], axis=2)
        d = full @ np.asarray(e["value"])
        ref = pred.ref
        pred.ref = replace(
            ref,
            omega=ref.omega + d[:, :3],
            acc_world=ref.acc_world + np.einsum("tij,tj->ti", ref.R, d[:, 3:]),
        )
    return [out]


def _settle(
    rec: Recording, model: RobotModel, opts: RobotOptions, rigid: Prediction, k: int
) -> tuple[Prediction, dict[str, object]]:
    """The rigid model against one whose feet settle in and out over the forces' ramp time: the
    residual energy per channel of both on the same samples (nothing is fitted to the IMU, so every
    sample is held out), and the prediction to go on with."""
    window = float(rigid.notes["contacts"]["settle_s"])
    soft = predict_encoders(rec, model, replace(opts, settle_s=window), [], k) if window > 0 else None
    effect: dict[str, object] = {"effect": "contact_settling", "params": {"window_s": window}, "named": False}
    if soft is None:
        return rigid, effect
    r0, use, block = _rigid_residual(rigid, opts)
    effect["rigid_rms"] = {
        "gyro": float(np.sqrt(np.mean(r0[use][:, :3] ** 2))),
        "acc": float(np.sqrt(np.mean(r0[use][:, 3:] ** 2))),
    }
    r1, _, _ = _rigid_residual(soft, opts)
    gains = {
        ch: float(1 - np.sum(r1[use][:, s] ** 2) / np.sum(r0[use][:, s] ** 2))
        for ch, s in (("gyro", slice(0, 3)), ("acc", slice(3, 6)))
    }
    per_block = [
        1 - np.sum(r1[use & (block == b)] ** 2) / np.sum(r0[use & (block == b)] ** 2)
        for b in np.unique(block[use])
    ]
    effect.update(
        channel_gain=gains,
        gain=float(np.mean(list(gains.values()))),
        block_gains=[float(g) for g in per_block],
    )
    effect["named"] = bool(max(gains.values()) >= opts.min_gain and np.median(per_block) > 0)
    return (soft if effect["named"] else rigid), effect


def _fill_nan(x: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x[:, 0])
    idx = np.arange(x.shape[0])
    return np.stack([np.interp(idx, idx[ok], x[ok, i]) for i in range(x.shape[1])], axis=1)


def predict_mocap(
    rec: Recording, model: RobotModel, opts: RobotOptions, could_not: list[str], k: int = 0
) -> Prediction | None:
    """The IMU predicted from the motion-capture base pose through the URDF mount (None without one)."""
    if "base_pos" not in rec.extra or "base_rot" not in rec.extra:
        could_not.append("mocap prediction: the recording has no base pose (extra base_pos, base_rot)")
        return None
    t, _ = _uniform(rec)
    pos = _interp(t, rec.t, np.asarray(rec.extra["base_pos"], float))
    rpy = np.unwrap(np.asarray(rec.extra["base_rot"], float), axis=0)
    R_wb = Rotation.from_euler("xyz", _interp(t, rec.t, rpy))
    R_bi = Rotation.from_matrix(model.imu_in_root[:3, :3])
    quat_xyzw = (R_wb * R_bi).as_quat()
    p_wi = pos + R_wb.apply(model.imu_in_root[:3, 3])
    ref = reference_motion(t, np.roll(quat_xyzw, 1, axis=1), p_wi, rec.gravity, opts.cutoff)
    gyro = _interp(t, rec.t, rec.gyro[:, k])
    acc = _interp(t, rec.t, rec.acc[:, k])
    notes = {"pose": "extra base_pos (m), base_rot (roll-pitch-yaw, fixed axes x-y-z)"}
    return Prediction("mocap", ref, gyro, acc, np.ones(t.size, bool), notes)


def _channel_gain(held: dict[str, object]) -> dict[str, float]:
    """Held-out gain per channel: 1 - (RMS after / RMS before)² on the held-out blocks."""
    return {
        ch: float(1.0 - (held[f"{ch}_after"] / held[f"{ch}_before"]) ** 2)
        for ch in ("gyro", "acc")
        if held.get(f"{ch}_before")
    }


def _analyze(
    pred: Prediction, opts: RobotOptions, expected_acc_delay: float, first: list[dict[str, object]] = ()
) -> dict[str, object]:
    """The robot's body effects on the rigid model's residual (named ones join the model), the
    held-out selection of IMU effects (:mod:`bodyschema.discrepancy`), then the accelerometer's own
    delay and the residual near contact changes (:mod:`bodyschema.floating_effects`)."""
    extended = list(first) + _extend(pred, opts)
    from bodyschema.discrepancy import analyze
    from bodyschema.discrepancy.fit import residual

    rep = analyze(
        pred.ref,
        pred.gyro,
        pred.acc,
        pred.valid,
        cutoff=opts.cutoff,
        n_blocks=opts.n_blocks,
        alpha=opts.alpha,
        min_gain=opts.min_gain,
    )
    out = rep.to_json()
    for key in ("structure_before", "structure_after", "screening"):
        out.pop(key, None)
    out["prediction"] = pred.name
    out["notes"] = pred.notes
    for c in out["causes"]:
        c["reading"] = _reading(c)
    prob = rep.problem
    idx = prob.index
    fitted = {k: v for k, v in rep.params.items() if k != "noise"}
    res, model = residual(prob, fitted)
    ta = prob.ref.t[idx]
    block = np.floor((ta - ta[0]) / 2.0).astype(int)  # the analysis's 2 s evidence blocks
    robot = list(extended)
    after = {"gyro": res[idx, :3].copy(), "acc": res[idx, 3:].copy()}
    dacc = np.gradient(model[:, 3:], prob.ref.t, axis=0)[idx]
    e = linear_effect("acc_delay", after["acc"], -dacc[..., None], block, opts.alpha, opts.min_gain)
    e.update(channel="acc", unit="s", expected=expected_acc_delay)
    robot.append(e)
    if e["named"]:
        after["acc"] = after["acc"] - (-dacc[..., None]) @ np.asarray(e["value"])
    if pred.near_change is not None:
        near = _interp(ta, pred.ref.t, pred.near_change.astype(float)) > 0.5
        robot.append(
            {
                **transition_ratio(
                    np.concatenate([after["gyro"], after["acc"]], 1) / prob.scale.repeat(3), near, block
                ),
                "channel": "both, normalised",
            }
        )
    out["robot_effects"] = robot
    out["held_out"]["channel_gain"] = _channel_gains(rep.held_out, robot)
    return out


#: A MEMS IMU's scale tolerance (MPU-6050 datasheet: ±3 %): a scale error well beyond it is the
#: model's error showing through the IMU, not the sensor's.
SENSOR_SCALE_TOL = 0.03
#: The same datasheet's accelerometer zero-g offset, the worst axis (±80 mg on z), m/s².
SENSOR_ACC_BIAS_TOL = 0.08 * 9.81


def _reading(cause: dict[str, object]) -> str:
    """What a named IMU effect says on a robot: a scale or an accelerometer bias beyond three times
    a sensor's tolerance is the rigid model getting that axis wrong, not the IMU."""
    if cause["effect"] in ("gyro_scale", "acc_scale"):
        worst = float(np.max(np.abs(np.ravel(cause["params"]["matrix"]) - 1.0)))
        if worst > 3 * SENSOR_SCALE_TOL:
            return (
                f"scale off by {worst:.0%}, beyond 3x a sensor's ±3 %: the rigid model's error on that axis"
            )
    if cause["effect"] == "acc_bias":
        worst = float(np.max(np.abs(cause["params"]["vector"])))
        if worst > 3 * SENSOR_ACC_BIAS_TOL:
            return (
                f"bias of {worst:.2f} m/s², beyond 3x a sensor's ±{SENSOR_ACC_BIAS_TOL:.2f} m/s²: "
                "the rigid model's error on that axis"
            )
    return "sensor or mount"


def _channel_gains(held: dict[str, object], robot: list[dict[str, object]]) -> dict[str, float]:
    """Held-out gain per channel, 1 - (RMS after / RMS before)²: of the IMU effects alone (the
    analysis's folds, on the model the body effects extended), and of the whole extension against
    the rigid model (each named effect's held-out share of what the others leave, multiplied)."""
    out = {}
    for ch in ("gyro", "acc"):
        g = 1.0 - (held[f"{ch}_rms_after"] / held[f"{ch}_rms_before"]) ** 2
        out[f"{ch}_imu_effects"] = float(g)
        keep = 1.0 - g
        for e in robot:
            if not e.get("named"):
                continue
            if "channel_gain" in e:
                keep *= 1.0 - float(e["channel_gain"][ch])
            elif e.get("channel") == ch:
                keep *= 1.0 - float(e["gain"])
        out[ch] = float(1.0 - keep)
    return out


def _agreement(
    reports: dict[str, dict[str, object]], enc: Prediction | None, mocap: Prediction | None, blocks: int
) -> dict[str, object]:
    """The two predictions' agreement (:func:`sim2real.robot_agreement.agreement`) and whether each
    estimate closes over what lies between the predictions themselves: the lag, then (on the mocap
    moved by it) the rotation between their base rates, the encoders' final model against the mocap."""
    out = agreement(reports)
    if not out or enc is None or mocap is None:
        return out
    t, use = enc.ref.t, _inner(enc)
    moc = _interp(t, mocap.ref.t, mocap.ref.omega)
    lag = prediction_lag(t, enc.ref.omega, moc, use, blocks)
    if "time_offset" in out:
        out["time_offset"]["closure"] = closure(out["time_offset"], lag, -1)
    if "mounting_rotation" in out:
        moved = _interp(t, mocap.ref.t + lag["estimate"][0], mocap.ref.omega)
        turn = prediction_rotation(t, enc.ref.omega, moved, use, blocks)
        out["mounting_rotation"]["closure"] = closure(out["mounting_rotation"], turn, +1)
    return out


def _acc_hold_delay(rec: Recording, k: int) -> float:
    """The accelerometer's lag behind the gyro its hold implies: half the update period beyond the
    log's own step when the import report says it updates slower than the log (0 otherwise)."""
    if "import_report" not in rec.extra:
        return 0.0
    streams = json.loads(str(rec.extra["import_report"])).get("streams", {})
    name = rec.imu_names[k]
    up_a = streams.get(f"acc:{name}", {}).get("update_rate_hz")
    up_g = streams.get(f"gyro:{name}", {}).get("update_rate_hz")
    if not up_a or not up_g or up_a > 0.8 * up_g:
        return 0.0
    return float(0.5 / up_a - 0.5 / up_g)


def robot_sim2real(
    rec: Recording, urdf: str | Path, options: RobotOptions | None = None, imu: int = 0
) -> dict[str, object]:
    """What the rigid model of a floating-base robot gets wrong about its base IMU, per prediction
    (``"encoders"``, ``"mocap"`` where the recording has a base pose), with the contacts, the encoder
    quantization floor, the two predictions' agreement and what could not be done."""
    opts = options or RobotOptions()
    model = read_robot(urdf, rec.joint_names)
    could_not: list[str] = []
    if model.unmatched:
        could_not.append(f"joints of the legs not in the recording, held at 0: {model.unmatched}")
    if rec.q is None:
        raise ValueError("the recording has no joint positions (q): nothing drives the rigid model")
    rate = 1.0 / float(np.median(np.diff(rec.t)))
    q_mid = np.median(rec.q, axis=0)[None]
    lever = float(np.median([np.linalg.norm(chain_frames(c, q_mid)[1][0]) for c in model.feet.values()]))
    legs = max(len(c.columns) for c in model.feet.values())
    quantum = _quantum(rec)
    if quantum is None:
        could_not.append(
            "encoder quantization: the import report resolved no quantum (floor and band not derived)"
        )
    if opts.cutoff is None:
        cut = 10.0 if quantum is None else band_cutoff(quantum, rate, lever, legs, opts.quantization_tol)
        opts = replace(opts, cutoff=round(cut, 2))
    floor = None
    if quantum is not None:
        floor = {
            "quantum_rad": quantum,
            "lever_m": lever,
            "joints": legs,
            **quantization_floor(quantum, rate, opts.cutoff, lever, legs),
        }
    delay = _acc_hold_delay(rec, imu)
    reports = {}
    enc = predict_encoders(rec, model, opts, could_not, imu)
    if enc is not None:
        enc, settle = _settle(rec, model, opts, enc, imu)
        reports["encoders"] = _analyze(enc, opts, delay, [settle])
    mocap = predict_mocap(rec, model, opts, could_not, imu)
    if mocap is not None:
        reports["mocap"] = _analyze(mocap, opts, delay)
    return {
        "robot": model.name,
        "imu": rec.imu_names[imu],
        "imu_mount": {"source": model.imu_source, "in_root": model.imu_in_root.round(6).tolist()},
        "feet": {"names": list(model.feet), "flat": model.flat},
        "cutoff_hz": opts.cutoff,
        "predictions": reports,
        "agreement": _agreement(reports, enc, mocap, opts.n_blocks),
        "encoder_quantization": floor,
        "could_not": could_not,
    }
