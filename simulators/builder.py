"""Build MuJoCo models (``mujoco.MjSpec``) with IMUs: from a description, or by instrumenting a file.

Every IMU is a site on a link's surface with z along the outward normal (x/y turned by an arbitrary,
seeded angle about it, as in the paper's experiment), an ``accelerometer`` and a ``gyro`` sensor on it.
Every robot joint (a named hinge or slide) gets three actuators the excitations drive: ``<j>:torque``
(a motor), ``<j>:pos`` and ``<j>:vel`` (position and velocity servos whose gains are set at run time,
zero when unused).

Names are the contract with the rest of the system: IMUs are ``imu0``, ``imu1``, … in build order
(base first, then links depth-first), sensors ``imuN:acc``/``imuN:gyro``; joints keep the names the
description or the file gives them.

Example
-------
>>> from simulators.description import LinkSpec, RobotDescription
>>> desc = RobotDescription("one", (LinkSpec("l1", "j1", end=(0.2, 0, 0)),), imus_per_link=2)
>>> model = build_spec(desc).compile()
>>> [model.site(i).name for i in range(model.nsite)], model.nu
(['imu0', 'imu1'], 3)
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence

import mujoco
import numpy as np

from simulators.description import LinkSpec, RobotDescription

__all__ = [
    "LOOSE_PREFIX",
    "add_drive",
    "add_imus",
    "build_spec",
    "instrument",
    "load_spec",
    "robot_joint_names",
    "surface_frames",
]

#: Joints whose name starts with this were added by damage (a loose IMU, a broken link): they are not
#: robot joints and anything hanging from them follows no robot joint.
LOOSE_PREFIX = "loose:"

_G = mujoco.mjtGeom
_J = mujoco.mjtJoint


def load_spec(path: str | os.PathLike[str]) -> mujoco.MjSpec:
    """Read an MJCF or URDF file into an editable spec; raise ``ValueError`` saying why it failed."""
    try:
        spec = mujoco.MjSpec.from_file(os.fspath(path))
    except (ValueError, OSError, RuntimeError) as err:
        raise ValueError(f"{path}: cannot load a MuJoCo model ({err})") from err
    _name_anonymous(spec)
    return spec


def _name_anonymous(spec: mujoco.MjSpec) -> None:
    for i, body in enumerate(spec.bodies):
        if body.name == "" and body is not spec.worldbody:
            body.name = f"body{i}"
    for i, joint in enumerate(spec.joints):
        if joint.name == "":
            joint.name = f"joint{i}"


def robot_joint_names(spec_or_model: mujoco.MjSpec | mujoco.MjModel) -> list[str]:
    """Names of the robot joints (hinge and slide, not added by damage), in model order."""
    if isinstance(spec_or_model, mujoco.MjSpec):
        joints = [(j.name, j.type) for j in spec_or_model.joints]
    else:
        m = spec_or_model
        joints = [(m.joint(i).name, _J(int(m.jnt_type[i]))) for i in range(m.njnt)]
    return [n for n, t in joints if t in (_J.mjJNT_HINGE, _J.mjJNT_SLIDE) and not n.startswith(LOOSE_PREFIX)]


def add_drive(spec: mujoco.MjSpec, joints: Sequence[str] | None = None) -> None:
    """Give each robot joint the torque / position / velocity actuators the excitations use.

    Gains are placeholders; :mod:`simulators.excitation` sets them on the compiled model.
    """
    existing = {a.name for a in spec.actuators}
    for j in robot_joint_names(spec) if joints is None else joints:
        if f"{j}:torque" in existing:
            continue
        a = spec.add_actuator(name=f"{j}:torque", target=j, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.set_to_motor()
        a = spec.add_actuator(name=f"{j}:pos", target=j, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.set_to_position(kp=1.0)
        a = spec.add_actuator(name=f"{j}:vel", target=j, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.set_to_velocity(kv=1.0)


# --------------------------------------------------------------------------- surface placement
def _cylinder(radius: float, half_len: float, k: int) -> tuple[np.ndarray, np.ndarray]:
    around = k if k < 4 else 4
    rows = math.ceil(k / around)
    pts, nrm = [], []
    for i in range(k):
        r, c = divmod(i, around)
        z = -half_len + (r + 0.5) * 2.0 * half_len / rows
        ang = 2.0 * math.pi * c / around + (math.pi / around if r % 2 else 0.0)
        n = np.array([math.cos(ang), math.sin(ang), 0.0])
        nrm.append(n)
        pts.append(radius * n + [0.0, 0.0, z])
    return np.array(pts), np.array(nrm)


def _sphere_dirs(k: int) -> np.ndarray:
    # Fibonacci lattice: near-uniform directions for any k.
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _box(half: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    faces = []
    for ax in range(3):
        others = [a for a in range(3) if a != ax]
        area = half[others[0]] * half[others[1]]
        for sign in (1.0, -1.0):
            faces.append((area, ax, sign, others))
    faces.sort(key=lambda f: -f[0])
    per_face = [0] * 6
    for i in range(k):
        per_face[i % 6] += 1
    pts, nrm = [], []
    for (_, ax, sign, others), m in zip(faces, per_face, strict=True):
        long_ax = max(others, key=lambda a: half[a])
        for j in range(m):
            p = np.zeros(3)
            p[ax] = sign * half[ax]
            p[long_ax] = half[long_ax] * (-1.0 + 2.0 * (j + 0.5) / m) * 0.8
            n = np.zeros(3)
            n[ax] = sign
            pts.append(p)
            nrm.append(n)
    return np.array(pts), np.array(nrm)


def _geom_surface(model: mujoco.MjModel, g: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``k`` surface points and outward normals of geom ``g`` in the geom frame."""
    gtype, size = _G(int(model.geom_type[g])), model.geom_size[g]
    if gtype in (_G.mjGEOM_CAPSULE, _G.mjGEOM_CYLINDER):
        return _cylinder(float(size[0]), float(size[1]), k)
    if gtype == _G.mjGEOM_SPHERE:
        d = _sphere_dirs(k)
        return d * size[0], d
    if gtype == _G.mjGEOM_ELLIPSOID:
        d = _sphere_dirs(k)
        p = d * size
        n = p / size**2
        return p, n / np.linalg.norm(n, axis=1, keepdims=True)
    if gtype == _G.mjGEOM_BOX:
        return _box(np.asarray(size, dtype=float), k)
    # meshes and anything else: the geom's bounding box
    aabb = model.geom_aabb[g]
    p, n = _box(np.maximum(np.asarray(aabb[3:], dtype=float), 1e-3), k)
    return p + aabb[:3], n


def _frame_quat(normal: np.ndarray, spin: float) -> np.ndarray:
    z = normal / np.linalg.norm(normal)
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(spin), math.sin(spin)
    x, y = c * x + s * y, -s * x + c * y
    mat = np.stack([x, y, z], axis=1)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, mat.reshape(-1))
    return quat


def surface_frames(
    model: mujoco.MjModel, body: int, k: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``k`` IMU frames on ``body``'s largest geom: positions (k,3) and wxyz quats (k,4), body frame.

    z is the outward surface normal; x/y are turned about it by an angle drawn from ``rng``.
    Raises ``ValueError`` for a body without a solid geom.
    """
    geoms = [
        g
        for g in range(model.ngeom)
        if model.geom_bodyid[g] == body
        and _G(int(model.geom_type[g])) not in (_G.mjGEOM_PLANE, _G.mjGEOM_HFIELD)
    ]
    if not geoms:
        raise ValueError(f"body {model.body(body).name!r} has no geometry to mount IMUs on")
    g = max(geoms, key=lambda i: float(model.geom_rbound[i]))
    pts, nrm = _geom_surface(model, g, k)
    rg = np.zeros(9)
    mujoco.mju_quat2Mat(rg, model.geom_quat[g])
    rg = rg.reshape(3, 3)
    pos = pts @ rg.T + model.geom_pos[g]
    nb = nrm @ rg.T
    quats = np.array([_frame_quat(n, float(rng.uniform(0.0, 2.0 * math.pi))) for n in nb])
    return pos, quats


def _next_imu_index(spec: mujoco.MjSpec) -> int:
    idx = [int(s.name[3:]) for s in spec.sites if s.name.startswith("imu") and s.name[3:].isdigit()]
    return max(idx, default=-1) + 1


def add_imus(
    spec: mujoco.MjSpec,
    counts: dict[str, int],
    rng: np.random.Generator,
) -> list[str]:
    """Add ``counts[body]`` IMUs (site + accelerometer + gyro) to each named body; return the new names.

    Bodies are handled in the order of ``counts``; numbering continues after the spec's existing IMUs.
    """
    model = spec.compile()
    nxt = _next_imu_index(spec)
    names: list[str] = []
    for body_name, k in counts.items():
        if k <= 0:
            continue
        try:
            bid = model.body(body_name).id
        except KeyError as err:
            raise ValueError(f"unknown body {body_name!r}") from err
        pos, quats = surface_frames(model, bid, k, rng)
        body = spec.body(body_name)
        for p, q in zip(pos, quats, strict=True):
            name = f"imu{nxt}"
            nxt += 1
            body.add_site(
                name=name, pos=p.tolist(), quat=q.tolist(), size=[0.006, 0.0, 0.0], rgba=[0.9, 0.1, 0.1, 1.0]
            )
            site = mujoco.mjtObj.mjOBJ_SITE
            spec.add_sensor(
                name=f"{name}:acc", type=mujoco.mjtSensor.mjSENS_ACCELEROMETER, objtype=site, objname=name
            )
            spec.add_sensor(
                name=f"{name}:gyro", type=mujoco.mjtSensor.mjSENS_GYRO, objtype=site, objname=name
            )
            names.append(name)
    return names


def instrument(
    spec: mujoco.MjSpec,
    bodies: Iterable[str] | None = None,
    per_link: int = 2,
    seed: int = 0,
    drive: bool = True,
) -> list[str]:
    """Add IMUs to a model the user already has (MJCF/URDF loaded with :func:`load_spec`).

    ``bodies`` None means every body with geometry except the world. Also adds the excitation
    actuators unless ``drive`` is false. Returns the new IMU names.

    >>> spec = mujoco.MjSpec.from_string(
    ...     '<mujoco><worldbody><body name="a"><joint name="h" axis="0 0 1"/>'
    ...     '<geom type="box" size=".1 .05 .02"/></body></worldbody></mujoco>')
    >>> instrument(spec, per_link=3)
    ['imu0', 'imu1', 'imu2']
    """
    _name_anonymous(spec)
    model = spec.compile()
    if bodies is None:
        with_geom = {int(b) for b in model.geom_bodyid}
        chosen = [model.body(b).name for b in range(1, model.nbody) if b in with_geom]
    else:
        chosen = list(bodies)
    names = add_imus(spec, {b: per_link for b in chosen}, np.random.default_rng(seed))
    if drive:
        add_drive(spec)
    return names


# --------------------------------------------------------------------------- from a description
def _add_link(spec: mujoco.MjSpec, parent: mujoco.MjsBody, link: LinkSpec, desc: RobotDescription) -> None:
    body = parent.add_body(name=link.name, pos=list(link.pos), quat=list(link.quat))
    joint = body.add_joint(
        name=link.joint,
        type=_J.mjJNT_HINGE,
        axis=list(link.axis),
        damping=desc.damping,
        armature=desc.armature,
    )
    if link.range is not None:
        joint.range = list(link.range)
        joint.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    end = np.asarray(link.end, dtype=float)
    if np.linalg.norm(end) < 1e-9:
        body.add_geom(
            type=_G.mjGEOM_SPHERE, size=[link.radius, 0, 0], mass=link.mass, contype=0, conaffinity=0
        )
    else:
        body.add_geom(
            type=_G.mjGEOM_CAPSULE,
            fromto=[0, 0, 0, *end.tolist()],
            size=[link.radius, 0, 0],
            mass=link.mass,
            contype=0,
            conaffinity=0,
        )
    for child in link.children:
        _add_link(spec, body, child, desc)


def build_spec(desc: RobotDescription) -> mujoco.MjSpec:
    """The MJCF model of ``desc``: base, links, joints, drive actuators and IMUs (not yet compiled)."""
    names = [lk.joint for lk in desc.iter_links()]
    if len(set(names)) != len(names):
        raise ValueError(f"{desc.name}: joint names must be unique")
    spec = mujoco.MjSpec()
    spec.modelname = desc.name
    spec.compiler.degree = False  # ranges in the description are radians
    spec.option.timestep = 0.005
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    base = spec.worldbody.add_body(name="base", pos=[0, 0, 0])
    base.add_geom(
        type=_G.mjGEOM_BOX,
        size=list(desc.base_half_size),
        mass=desc.base_mass,
        contype=0,
        conaffinity=0,
        pos=[0, 0, -desc.base_half_size[2]],
    )
    for link in desc.links:
        _add_link(spec, base, link, desc)
    counts = {"base": desc.base_imus}
    for link in desc.iter_links():
        counts[link.name] = desc.imus_per_link if link.imus is None else link.imus
    add_imus(spec, counts, np.random.default_rng(desc.seed))
    add_drive(spec, names)
    return spec
