"""Random robots built apart from :mod:`simulators`, to check the product against bodies it did not make.

Every figure measured on robots from :mod:`simulators` shares that package's assumptions (how trees
are grown, how IMUs are mounted, how joints are driven and sensed). This generator shares no code
with it: it writes its own MuJoCo XML and drives MuJoCo directly.

* **Body**: a random labelled tree of hinge joints on a fixed base (names shuffled, so their order
  says nothing about the tree), random axes, link lengths and payload masses; one to a few IMUs
  (a site with a gyro and an accelerometer) per link at random poses. Links collide with each other
  (MuJoCo's default filter leaves out only a body and its parent), so some joints jam; a share of
  the joints has a bearing that drags about as hard as its servo can push, and hardly moves.
* **Drive**: one velocity servo per joint (a ``velocity`` actuator with a torque limit, integrated
  explicitly so that the limit holds, with the reflected inertia of a geared motor) following
  a sum of slow sines (0.1-0.8 Hz) inside the joint's range, with a position term so that it does
  not wander.
* **Sensing** (:mod:`bench.generator_sensing`): MPU-6050 datasheet limits (docs/design.md, 'Facts the error
  models use') for noise, bias, scale and cross-axis; optionally its 42 Hz low-pass with 4.8 ms delay, encoder
  quantization and an IMU-to-encoder skew.
* **Output**: the same samples in two shapes, multi-rate (IMU stamps ``t``, encoder stamps ``t_q``,
  docs/recording-format.md) and single-clock (one ``t``, positions ``q`` only), with the truth.

Example
-------
>>> gen = generate(3, GeneratorOptions(joints=(5, 5), seconds=2.0))
>>> gen.multi.is_multirate, gen.single.is_multirate, gen.multi.n_joints
(True, False, 5)
>>> bool(np.array_equal(gen.multi.gyro, gen.single.gyro))
True
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from bench.generator_sensing import ImuErrors, SensingSpec, sample_at, sense_imus
from bodyschema.recording import Recording

__all__ = [
    "Generated",
    "GeneratorOptions",
    "RobotSpec",
    "build_xml",
    "generate",
    "random_spec",
    "save_npz",
    "truth_kinematics",
]


@dataclass(frozen=True)
class GeneratorOptions:
    """What kind of robot and sensing :func:`generate` draws; ranges are inclusive ``(low, high)``."""

    joints: tuple[int, int] = (5, 25)
    imus_per_link: tuple[int, int] = (1, 3)
    link_length: tuple[float, float] = (0.08, 0.35)
    link_radius: float = 0.02  # m; the payload sphere at a link's end is 1.5 times as wide
    seized: float = 0.1  # share of joints whose bearing drags about as hard as their servo can push
    payload_kg: tuple[float, float] = (0.05, 1.5)
    seconds: float = 60.0
    rate: float = 100.0
    encoder_rate: float = 100.0
    sim_rate: float = 500.0
    freq_hz: tuple[float, float] = (0.1, 0.8)
    sines: int = 3
    contacts: bool = True
    sensing: SensingSpec = field(default_factory=SensingSpec)

    def __post_init__(self) -> None:
        lo, hi = self.joints
        if not 1 <= lo <= hi:
            raise ValueError(f"joints must be 1 <= low <= high, got {self.joints}")
        for name in ("rate", "encoder_rate"):
            ratio = self.sim_rate / getattr(self, name)
            if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
                raise ValueError(f"{name} must divide sim_rate ({self.sim_rate:g} Hz)")
        ratio = self.encoder_rate / self.rate
        if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            raise ValueError("encoder_rate must be a whole multiple of rate (the IMU rate)")
        if self.seconds <= 0:
            raise ValueError("seconds must be positive")


@dataclass(frozen=True)
class RobotSpec:
    """A drawn robot. Link ``i`` (1..N, in tree order) hangs on link ``parent[i-1]`` (0 = base) by a
    hinge named ``joint_names[i-1]``; IMU ``k`` rides link ``imu_link[k]``."""

    parent: tuple[int, ...]
    joint_names: tuple[str, ...]
    offset: np.ndarray  # (N, 3) joint position in the parent link's frame
    link: np.ndarray  # (N, 3) link vector in its own frame
    axis: np.ndarray  # (N, 3) unit hinge axes in the link's frame
    limits: np.ndarray  # (N, 2) rad
    payload: np.ndarray  # (N,) kg
    imu_names: tuple[str, ...]
    imu_link: tuple[int, ...]
    imu_pos: np.ndarray  # (K, 3) in the link's frame
    imu_quat: np.ndarray  # (K, 4) wxyz, link frame to IMU frame


@dataclass(frozen=True)
class Generated:
    """One robot's two recordings and what only the generator knows."""

    multi: Recording
    single: Recording
    spec: RobotSpec
    xml: str
    qd_true: np.ndarray  # (T, N) joint rates at the IMU samples' physical instants, recording order
    imu_errors: ImuErrors
    skew: float  # s, clock skew alone (truth_skew adds the filter delay)


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def random_spec(rng: np.random.Generator, options: GeneratorOptions) -> RobotSpec:
    """Draw a tree, its geometry and its IMU mounts (no physics yet)."""
    o = options
    n = int(rng.integers(o.joints[0], o.joints[1] + 1))
    # a random recursive tree, the base taking a share like any link plus a little
    parent = tuple(0 if rng.random() < 0.15 else int(rng.integers(0, i)) for i in range(1, n + 1))
    labels = rng.permutation(n)
    joint_names = tuple(f"j{labels[i]:02d}" for i in range(n))
    lengths = rng.uniform(*o.link_length, size=n)
    link = _unit(rng, n) * lengths[:, None]
    offset = np.zeros((n, 3))
    for i, p in enumerate(parent):
        offset[i] = (rng.uniform(-0.08, 0.08, 3) * [1, 1, 0] + [0, 0, 0.1]) if p == 0 else link[p - 1]
    lo = -rng.uniform(0.6, 2.5, n)
    hi = rng.uniform(0.6, 2.5, n)
    imu_link: list[int] = []
    for i in range(1, n + 1):
        imu_link += [i] * int(rng.integers(o.imus_per_link[0], o.imus_per_link[1] + 1))
    k = len(imu_link)
    along = rng.uniform(0.15, 1.0, k)[:, None]
    side = _unit(rng, k)
    lv = link[np.array(imu_link) - 1]
    perp = side - (np.sum(side * lv, 1) / np.sum(lv * lv, 1))[:, None] * lv
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    quat = rng.normal(size=(k, 4))
    ilabels = rng.permutation(k)
    return RobotSpec(
        parent=parent,
        joint_names=joint_names,
        offset=offset,
        link=link,
        axis=_unit(rng, n),
        limits=np.c_[lo, hi],
        payload=rng.uniform(*o.payload_kg, n),
        imu_names=tuple(f"imu{ilabels[j]:02d}" for j in range(k)),
        imu_link=tuple(imu_link),
        imu_pos=along * lv + 0.03 * perp,
        imu_quat=quat / np.linalg.norm(quat, axis=1, keepdims=True),
    )


def _v(x: np.ndarray) -> str:
    return " ".join(f"{float(a):.6g}" for a in x)


def build_xml(
    spec: RobotSpec,
    options: GeneratorOptions,
    gains: np.ndarray | None = None,
    forces: np.ndarray | None = None,
    friction: np.ndarray | None = None,
) -> str:
    """MuJoCo XML of ``spec``: capsule links with a payload sphere at the end, hinge joints, IMU sites
    with gyro and accelerometer sensors, one torque-limited velocity servo per joint."""
    n = len(spec.parent)
    children: dict[int, list[int]] = {}
    for i, p in enumerate(spec.parent, start=1):
        children.setdefault(p, []).append(i)
    imus_on: dict[int, list[int]] = {}
    for k, li in enumerate(spec.imu_link):
        imus_on.setdefault(li, []).append(k)
    contact = 'contype="1" conaffinity="1"' if options.contacts else 'contype="0" conaffinity="0"'

    g = np.full(n, 10.0) if gains is None else gains
    # a geared servo's reflected rotor inertia, sized with its gain: explicit velocity feedback stays
    # stable while gain x timestep / inertia is under 2; here it is at most 1
    arm = np.maximum(0.01, g / options.sim_rate)

    def body(i: int, depth: int) -> list[str]:
        pad = "  " * depth
        name, lv = spec.joint_names[i - 1], spec.link[i - 1]
        lo, hi = spec.limits[i - 1]
        out = [
            f'{pad}<body name="L{name}" pos="{_v(spec.offset[i - 1])}">',
            f'{pad}  <joint name="{name}" type="hinge" axis="{_v(spec.axis[i - 1])}" limited="true" '
            f'range="{lo:.6g} {hi:.6g}" damping="0.05" armature="{arm[i - 1]:.6g}" '
            f'frictionloss="{0.0 if friction is None else friction[i - 1]:.6g}"/>',
            # the capsule starts clear of the joint, so siblings sharing a joint point do not touch
            f'{pad}  <geom type="capsule" fromto="{_v(0.3 * lv)} {_v(lv)}" '
            f'size="{options.link_radius:.6g}" mass="0.1" {contact}/>',
            f'{pad}  <geom type="sphere" pos="{_v(lv)}" size="{1.5 * options.link_radius:.6g}" '
            f'mass="{spec.payload[i - 1]:.6g}" '
            f"{contact}/>",
        ]
        for k in imus_on.get(i, []):
            out.append(
                f'{pad}  <site name="{spec.imu_names[k]}" pos="{_v(spec.imu_pos[k])}" '
                f'quat="{_v(spec.imu_quat[k])}" size="0.005"/>'
            )
        for c in children.get(i, []):
            out += body(c, depth + 1)
        return [*out, f"{pad}</body>"]

    lines = [
        '<mujoco model="generated">',
        '  <compiler angle="radian"/>',
        '  <option timestep="%.6g" integrator="Euler" gravity="0 0 -9.81"/>' % (1.0 / options.sim_rate),
        "  <worldbody>",
        '    <body name="base">',
        '      <geom type="cylinder" size="0.1 0.05" pos="0 0 0.05" mass="5" contype="0" conaffinity="0"/>',
    ]
    for c in children.get(0, []):
        lines += body(c, 3)
    lines += ["    </body>", "  </worldbody>", "  <actuator>"]
    f = np.full(n, 1e3) if forces is None else forces
    for i, name in enumerate(spec.joint_names):
        lines.append(
            f'    <velocity name="v{name}" joint="{name}" kv="{g[i]:.6g}" forcelimited="true" '
            f'forcerange="{-f[i]:.6g} {f[i]:.6g}"/>'
        )
    lines += ["  </actuator>", "  <sensor>"]
    for s in spec.imu_names:
        lines += [f'    <gyro name="g{s}" site="{s}"/>', f'    <accelerometer name="a{s}" site="{s}"/>']
    return "\n".join([*lines, "  </sensor>", "</mujoco>", ""])


def _servo_sizing(
    model: mujoco.MjModel, spec: RobotSpec, rng: np.random.Generator, seized: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Servo gain and torque limit per joint from a bound on the gravity torque its subtree can load
    it with: the limit is 1.5x that bound (so a joint pushing into another link stalls instead of
    crushing through it), the gain turns the limit into a 0.1 rad/s velocity error. A share ``seized``
    of the joints gets dry friction of 0.7-1.3 times that limit (a bearing gone stiff): they hardly
    move, as a joint jammed against another link does, but for the whole recording."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    n = len(spec.parent)
    torque = np.zeros(n)
    for i, jid in enumerate(_qpos_index(model, spec)):
        b = model.jnt_bodyid[jid]
        anchor = data.xanchor[jid]
        sub = [c for c in range(model.nbody) if _descends(model, c, b)]
        reach = max(np.linalg.norm(data.xipos[c] - anchor) + 0.35 for c in sub)
        torque[i] = model.body_subtreemass[b] * 9.81 * reach
    force = 1.5 * torque + 1.0
    friction = np.where(rng.random(n) < seized, rng.uniform(0.7, 1.3, n), 0.0) * force
    return force / 0.1, force, friction


def _qpos_index(model: mujoco.MjModel, spec: RobotSpec) -> np.ndarray:
    """Where each spec joint sits in ``qpos`` (MuJoCo numbers joints depth first, not in spec order);
    every joint is a hinge, so the same index serves ``qvel`` and the joint arrays."""
    return np.array([model.joint(name).id for name in spec.joint_names])


def _descends(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = model.body_parentid[body]
    return False


def _reference(
    rng: np.random.Generator, spec: RobotSpec, options: GeneratorOptions, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Joint position and velocity references: a sum of slow sines inside each joint's range."""
    n = len(spec.parent)
    lo, hi = spec.limits[:, 0], spec.limits[:, 1]
    mid, half = (lo + hi) / 2, (hi - lo) / 2 - 0.1
    f = rng.uniform(*options.freq_hz, size=(n, options.sines))
    ph = rng.uniform(0, 2 * np.pi, size=(n, options.sines))
    w = rng.dirichlet(np.ones(options.sines), size=n) * (rng.uniform(0.4, 0.9, n) * half)[:, None]
    arg = 2 * np.pi * f[None] * t[:, None, None] + ph[None]
    q = mid + np.sum(w[None] * np.sin(arg), axis=2)
    qd = np.sum(w[None] * 2 * np.pi * f[None] * np.cos(arg), axis=2)
    return q, qd


def _simulate(
    model: mujoco.MjModel, spec: RobotSpec, q_ref: np.ndarray, qd_ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step the servos through the references; per step the positions and rates (spec order) and the
    IMU readings (:func:`_sensors`)."""
    data = mujoco.MjData(model)
    ix = _qpos_index(model, spec)
    data.qpos[ix] = q_ref[0]
    mujoco.mj_forward(model, data)
    steps = q_ref.shape[0]
    qpos = np.empty((steps, model.nq))
    kp = 4.0  # 1/s: the position term's bandwidth, well under the servo's
    for s in range(steps):
        qpos[s] = data.qpos
        data.ctrl[:] = qd_ref[s] + kp * (q_ref[s] - qpos[s, ix])
        mujoco.mj_step(model, data)
    qvel, sens = _sensors(model, qpos)
    return qpos[:, ix], qvel[:, ix], sens


def _sensors(model: mujoco.MjModel, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint rates and IMU readings of the trajectory ``qpos`` the encoders see.

    MuJoCo evaluates its sensors at a step's start, with that step's forward-dynamics acceleration,
    and then advances the positions with the velocity of the step's end (semi-implicit Euler), so a
    gyro read there lags the positions by half a step (1 ms at 500 Hz, which the fast estimator reads
    as skew). So the rates and accelerations are taken from the positions by central differences
    (second order: about 1e-5 relative error for 0.8 Hz at 500 Hz) and the sensors are evaluated on
    them by inverse dynamics (``mj_inverse``)."""
    dt = model.opt.timestep
    qvel = np.gradient(qpos, dt, axis=0)
    qacc = np.zeros_like(qpos)
    qacc[1:-1] = (qpos[2:] - 2 * qpos[1:-1] + qpos[:-2]) / dt**2
    data = mujoco.MjData(model)
    sens = np.empty((len(qpos), model.nsensordata), dtype=np.float32)
    for s in range(len(qpos)):
        data.qpos[:], data.qvel[:], data.qacc[:] = qpos[s], qvel[s], qacc[s]
        mujoco.mj_inverse(model, data)
        sens[s] = data.sensordata
    return qvel, sens


def generate(seed: int, options: GeneratorOptions | None = None) -> Generated:
    """Draw, simulate and sense one robot; the same ``seed`` and ``options`` give the same recordings."""
    o = options or GeneratorOptions()
    body_ss, drive_ss, sense_ss, servo_ss = np.random.SeedSequence([seed, 0x6E6]).spawn(4)
    warm = 0.1  # s simulated before the first stamp: room for the skew and the filters to settle
    dt = 1.0 / o.sim_rate
    steps = round((o.seconds + warm) * o.sim_rate) + 1
    ts = -warm + dt * np.arange(steps)
    spec = _free_of_contacts(np.random.default_rng(body_ss), o, drive_ss, ts[:1])
    probe = mujoco.MjModel.from_xml_string(build_xml(spec, o))
    gains, forces, friction = _servo_sizing(probe, spec, np.random.default_rng(servo_ss), o.seized)
    xml = build_xml(spec, o, gains, forces, friction)
    model = mujoco.MjModel.from_xml_string(xml)
    q_ref, qd_ref = _reference(np.random.default_rng(drive_ss), spec, o, ts)
    qpos, qvel, sens = _simulate(model, spec, q_ref, qd_ref)
    t = np.arange(round(o.seconds * o.rate)) / o.rate
    imu = sense_imus(np.random.default_rng(sense_ss), sens, ts, t, o.sensing)
    i_warm = round(warm * o.sim_rate)
    every = round(o.sim_rate / o.encoder_rate)
    t_q = ts[i_warm::every][: round(o.seconds * o.encoder_rate)]
    t_q = np.arange(t_q.size) / o.encoder_rate  # the same instants, stamped without rounding noise
    q_enc = o.sensing.quantize(qpos[i_warm::every][: t_q.size])
    order = np.argsort(spec.joint_names)
    iorder = np.argsort(spec.imu_names)
    names = tuple(spec.joint_names[i] for i in order)
    truth_parent = tuple("" if spec.parent[i] == 0 else spec.joint_names[spec.parent[i] - 1] for i in order)
    truth_imu = tuple(spec.joint_names[spec.imu_link[k] - 1] for k in iorder)
    axis, lever = truth_kinematics(model, spec)
    extra = {
        "sensing": np.array(json.dumps(o.sensing.to_json())),
        "truth_skew": np.array(o.sensing.truth_lag()),
        "truth_axis": axis[iorder],
        "truth_lever_arm": lever[iorder],
    }
    common = {
        "t": t,
        "joint_names": names,
        "imu_names": tuple(spec.imu_names[k] for k in iorder),
        "acc": imu.acc[:, iorder],
        "gyro": imu.gyro[:, iorder],
        "truth_joint_parent": truth_parent,
        "truth_imu_joint": truth_imu,
    }
    multi = Recording(t_q=t_q, q=q_enc[:, order], extra=dict(extra), **common)
    m = round(o.encoder_rate / o.rate)
    single = Recording(q=q_enc[::m][: t.size, order], extra=dict(extra), **common)
    return Generated(
        multi=multi,
        single=single,
        spec=spec,
        xml=xml,
        qd_true=sample_at(qvel, ts, t - o.sensing.skew)[:, order],
        imu_errors=imu.errors.reorder(iorder),
        skew=o.sensing.skew,
    )


def _free_of_contacts(
    rng: np.random.Generator,
    o: GeneratorOptions,
    drive: np.random.SeedSequence,
    t0: np.ndarray,
    tries: int = 8,
) -> RobotSpec:
    """A spec whose links do not touch at the start of the motion (a robot is assembled without
    interpenetration; it may collide once it moves). Redraws the geometry until one fits."""
    spec = random_spec(rng, o)
    for _ in range(tries):
        model = mujoco.MjModel.from_xml_string(build_xml(spec, o))
        data = mujoco.MjData(model)
        data.qpos[_qpos_index(model, spec)] = _reference(np.random.default_rng(drive), spec, o, t0)[0][0]
        mujoco.mj_forward(model, data)
        if data.ncon == 0 or not o.contacts:
            return spec
        spec = random_spec(rng, o)
    return spec


def truth_kinematics(model: mujoco.MjModel, spec: RobotSpec) -> tuple[np.ndarray, np.ndarray]:
    """Per IMU (spec order) the axis of the joint moving its link and the perpendicular lever arm from
    that axis to the IMU, both in the IMU frame (docs/kinematics.md, 'JSON'). Constant on a
    rigid link, so read at the model's zero pose."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    k = len(spec.imu_names)
    axis, lever = np.zeros((k, 3)), np.zeros((k, 3))
    ix = _qpos_index(model, spec)
    for j, name in enumerate(spec.imu_names):
        sid = model.site(name).id
        jid = ix[spec.imu_link[j] - 1]
        R = data.site_xmat[sid].reshape(3, 3)
        a = data.xaxis[jid] / np.linalg.norm(data.xaxis[jid])
        r = data.site_xpos[sid] - data.xanchor[jid]
        axis[j] = R.T @ a
        lever[j] = R.T @ (r - (r @ a) * a)
    return axis, lever


def save_npz(rec: Recording, path: str | Path) -> None:
    """Write ``rec`` as docs/recording-format.md describes (names as unicode arrays, no pickles)."""
    data: dict[str, np.ndarray] = {}
    for key in ("t", "t_q", "q", "qd", "qdd", "acc", "gyro", "gravity", "ref_quat", "ref_pos"):
        v = getattr(rec, key)
        if v is not None:
            data[key] = np.asarray(v, dtype=np.float64)
    for key in ("joint_names", "imu_names", "truth_joint_parent", "truth_imu_joint"):
        v = getattr(rec, key)
        if v is not None:
            data[key] = np.asarray(list(v), dtype=np.str_)
    data.update(rec.extra)
    np.savez_compressed(path, **data)  # type: ignore[arg-type]
