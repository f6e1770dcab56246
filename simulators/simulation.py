"""One simulated robot end to end: physics, excitation, IMU error model, damage -> recordings.

:class:`Simulation` is what the farm runs per robot and what :func:`simulate` runs once. Randomness
comes from one seed, split into independent streams (excitation, IMU parameter draws, sensor noise,
damage choices), so adding damage does not change the motion or the noise of an otherwise equal run.

Example
-------
>>> rec = simulate("paper-2", seconds=0.5, seed=1, imu_model="ideal")
>>> rec.n_samples, rec.n_joints, rec.n_imus, rec.truth_joint_parent
(50, 5, 60, ('', 'j1', 'j2', 'j1', 'j4'))
>>> rec.extra["excitation"].shape
(5,)
"""

from __future__ import annotations

import copy
import json
import math
import os
from collections import deque
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from bodyschema.findings import Diff, Finding
from bodyschema.recording import Recording
from bodyschema.topology import Topology
from simulators.damage import apply_damage, parse_damage
from simulators.excitation import Excitation, excitation_rms, make_excitation
from simulators.imu_model import ImuModel, ImuStream, resolve_imu_model
from simulators.robot import Robot
from simulators.sensing import SensingOptions, apply_sensing, resolve_sensing

__all__ = ["Simulation", "simulate"]

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


def _make_robot(robot: str | Robot, rate: float) -> tuple[Robot, str]:
    if isinstance(robot, Robot):
        return robot, robot.name
    from simulators.catalog import CATALOG

    if robot in CATALOG:
        return Robot.from_catalog(robot, rate=rate), robot
    if os.path.exists(robot):
        return Robot.from_file(robot, rate=rate), robot
    raise ValueError(f"unknown robot {robot!r}: not in the catalog ({', '.join(CATALOG)}) nor a model file")


class Simulation:
    """A robot (catalog name, MJCF/URDF path or :class:`Robot`) producing recordings chunk by chunk.

    ``rate`` is the sample rate unless the IMU model sets ``sample_rate``. :meth:`advance` continues
    time from the previous chunk; :meth:`apply_damage` applies damage now. ``readahead`` (s) simulates at
    least that much per physics call and serves small chunks from the buffer, which saves the
    per-call cost when chunks are small; the returned data are the same either way. ``imu_seed``, when
    given, draws the IMUs' errors (biases, gains, misalignments) from a seed of their own: a real IMU
    keeps them from run to run while the motion changes, which comparing two runs of one body needs.
    """

    def __init__(
        self,
        robot: str | Robot,
        *,
        seed: int | Sequence[int] | np.random.SeedSequence = 0,
        imu_model: str | ImuModel | None = "mpu6050",
        excitation: str | Excitation = "observable",
        rate: float = 100.0,
        readahead: float = 0.0,
        imu_seed: int | Sequence[int] | np.random.SeedSequence | None = None,
    ) -> None:
        model = resolve_imu_model(imu_model)
        self.rate = float(model.rate or rate)
        self.robot, self.source = _make_robot(robot, self.rate)
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
        exc_ss, par_ss, noise_ss, dmg_ss = ss.spawn(4)
        if imu_seed is not None:
            own = isinstance(imu_seed, np.random.SeedSequence)
            par_ss = imu_seed if own else np.random.SeedSequence(imu_seed)  # type: ignore[arg-type]
        self.imu_model = model
        self.params = model.instantiate(self.robot.imu_names, np.random.default_rng(par_ss))
        self.stream = ImuStream(self.params, self.rate, self.robot.model.opt.gravity.copy())
        self.noise_rng = np.random.default_rng(noise_ss)
        self.damage_rng = np.random.default_rng(dmg_ss)
        self.excitation = make_excitation(excitation).bind(self.robot, np.random.default_rng(exc_ss))
        self.encoder_faults: dict[str, tuple[str, float]] = {}
        self._backlash_side: dict[str, float] = {}
        self.locked: set[str] = set()
        self.lost: set[str] = set()
        self.findings: list[Finding] = []
        self.damage_times: list[float] = []
        self.last_kwargs: dict[str, Any] = {}
        self._samples = 0  # simulated (may run ahead of what was returned)
        self._served = 0  # returned by advance
        self._readahead = max(0, round(readahead * self.rate))
        self._blocks: deque[list[Any]] = deque()
        self._truth: tuple[tuple[str, ...], tuple[str, ...], np.ndarray] | None = None
        self._ctrl_cache: tuple[int, np.ndarray] = (0, np.empty((0, self.robot.model.nu)))

    # ------------------------------------------------------------------ state
    @property
    def time(self) -> float:
        """Time of the next sample to be returned, s."""
        return self._served / self.rate

    @property
    def diff(self) -> Diff:
        """Ground truth of all damage so far."""
        return Diff(findings=tuple(self.findings))

    def truth(self) -> Topology:
        """Current ground truth from the compiled model (damage applied)."""
        return self.robot.truth()

    def recompile(self) -> None:
        """After a spec edit: recompile keeping the state, restore the excitation's gains."""
        self.robot.recompile()
        self.excitation.configure(self.robot)
        self._truth = None

    def record_damage(self, finding: Finding) -> None:
        self.findings.append(finding)
        self.damage_times.append(self.time)
        self._truth = None

    def apply_damage(self, kind: str, **kwargs: Any) -> Diff:
        """Apply damage now (see :mod:`simulators.damage`); return its ground-truth diff."""
        return apply_damage(self, kind, **kwargs)

    # ------------------------------------------------------------------ running
    def _ctrl(self, start: int, n: int) -> np.ndarray:
        # Commands are a pure function of time: compute a second ahead and slice, so small chunks
        # (the farm's) do not pay the excitation's per-call cost every time.
        c0, block = self._ctrl_cache
        if not (c0 <= start and start + n <= c0 + len(block)):
            m = max(n, int(self.rate))
            block = self.excitation.ctrl(self.robot, (start + np.arange(m)) / self.rate)
            c0 = start
            self._ctrl_cache = (c0, block)
        return block[start - c0 : start - c0 + n]

    def advance(self, n_samples: int | None = None, *, seconds: float | None = None) -> Recording:
        """The next ``n_samples`` samples (or ``seconds`` worth) as a recording (docs/design.md,
        'Recording')."""
        if n_samples is None:
            if seconds is None:
                raise ValueError("give n_samples or seconds")
            n_samples = round((self.time + seconds) * self.rate) - self._served
        elif isinstance(n_samples, bool) or not isinstance(n_samples, int | np.integer):
            # advance(60.0) reads as seconds but would be a sample count: refuse it rather than guess
            raise TypeError(f"n_samples must be an int (a count; use seconds= for time), got {n_samples!r}")
        if n_samples < 1:
            raise ValueError("a chunk needs at least one sample")
        while self._buffered() < n_samples:
            k = max(n_samples - self._buffered(), self._readahead)
            snap = self._snapshot() if self._readahead else None
            self._blocks.append([snap, self._produce(k), 0])
        parts = []
        need = n_samples
        while need:
            block = self._blocks[0]
            arrays, off = block[1], block[2]
            take = min(need, len(arrays["t"]) - off)
            parts.append({k: v[off : off + take] for k, v in arrays.items()})
            block[2] += take
            need -= take
            if block[2] == len(arrays["t"]):
                self._blocks.popleft()
        self._served += n_samples
        cat = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        r = self.robot
        if self._truth is None:
            self._truth = r.truth_arrays()
        jp, ij, detached = self._truth
        extra: dict[str, np.ndarray] = {"excitation": excitation_rms(cat["qd_body"])}
        if self.findings:
            extra["truth_diff"] = np.array(json.dumps(self.diff.to_json()))
            extra["damage_time"] = np.array(self.damage_times, dtype=np.float64)
            extra["truth_imu_detached"] = _detached_json(r.imu_names, detached)
        return Recording(
            t=cat["t"],
            joint_names=r.joint_names,
            q=cat["q"],
            qd=cat["qd"],
            qdd=cat["qdd"],
            imu_names=r.imu_names,
            acc=cat["acc"],
            gyro=cat["gyro"],
            gravity=np.array(r.model.opt.gravity, dtype=np.float64),
            truth_joint_parent=jp,
            truth_imu_joint=ij,
            extra=extra,
        )

    def _produce(self, n: int) -> dict[str, np.ndarray]:
        """Simulate ``n`` more samples: physics, IMU model, encoder faults (nothing served yet)."""
        r = self.robot
        t = (self._samples + np.arange(n)) / self.rate  # the rate grid (the physics clock, exactly)
        poses = self.stream.needs_poses
        s = r.sample(self._ctrl(self._samples, n), poses=poses)
        acc, gyro = self.stream.process(
            t, s.acc, s.gyro, self.noise_rng, gyro_dot=s.gyro_dot if poses else None, R=s.R if poses else None
        )
        q, qd, qdd = s.q, s.qd, s.qdd
        if self.encoder_faults:
            q, qd, qdd = q.copy(), qd.copy(), qdd.copy()
            for joint, (mode, value) in self.encoder_faults.items():
                j = r.joint_names.index(joint)
                if mode == "stuck":
                    q[:, j] = value
                    qd[:, j] = 0.0
                    qdd[:, j] = 0.0
                elif mode == "backlash":
                    q[:, j] += 0.5 * value * self._motor_side(joint, s.qd[:, j])
                elif mode == "scale":
                    q[:, j] *= value
                    qd[:, j] *= value
                    qdd[:, j] *= value
                else:
                    q[:, j] += value
        self._samples += n
        return {"t": t, "q": q, "qd": qd, "qdd": qdd, "acc": acc, "gyro": gyro, "qd_body": s.qd}

    def _motor_side(self, joint: str, qd: np.ndarray) -> np.ndarray:
        """Backlash: the side of the dead band the motor (and its encoder) is on, +1 or -1 per sample.

        The motor drives the link through the gap, so while the link moves the motor leads it by half
        the gap in the direction of motion; when the link rests the motor stays where it was. (The
        simulated link does not wait while the motor crosses the gap at a reversal: the encoder jumps
        by the gap there, the dead band as the IMU sees it.) The side carries over between chunks.
        """
        moving = np.abs(qd) > 1e-3
        side = np.where(moving, np.sign(qd), 0.0)
        last = self._backlash_side.get(joint, 1.0)
        idx = np.where(moving, np.arange(len(qd)), -1)
        np.maximum.accumulate(idx, out=idx)
        out = np.where(idx >= 0, side[np.maximum(idx, 0)], last)
        if len(out):
            self._backlash_side[joint] = float(out[-1])
        return out

    # ------------------------------------------------------------------ read-ahead
    def _buffered(self) -> int:
        return sum(len(b[1]["t"]) - b[2] for b in self._blocks)

    def _snapshot(self) -> tuple[Any, ...]:
        m, d = self.robot.model, self.robot.data
        state = np.empty(mujoco.mj_stateSize(m, _STATE))
        mujoco.mj_getState(m, d, state, _STATE)
        st = self.stream
        return (
            self._samples,
            state,
            st._t.copy(),
            st._hist.copy(),
            st._last.copy(),
            copy.deepcopy(self.noise_rng.bit_generator.state),
        )

    def sync(self) -> None:
        """Bring the physics back to the last served sample, dropping read-ahead samples.

        The state at the start of the oldest buffered block is restored and the part already served
        is simulated again (bit for bit the same), so damage injected now acts exactly at
        :attr:`time`, as without read-ahead.
        """
        if not self._blocks:
            return
        snap, _, off = self._blocks[0]
        self._blocks.clear()
        samples, state, hist_t, hist, last, rng_state = snap
        m, d = self.robot.model, self.robot.data
        mujoco.mj_setState(m, d, state, _STATE)
        st = self.stream
        st._t, st._hist, st._last = hist_t, hist, last
        self.noise_rng.bit_generator.state = rng_state
        self._samples = samples
        if off:
            self._produce(off)


def _detached_json(names: tuple[str, ...], mask: np.ndarray) -> np.ndarray:
    # a 0-d JSON string: an (K,) array could be mistaken for a time series by Recording.select
    return np.array(json.dumps([n for n, d in zip(names, mask, strict=True) if d]))


def _concat(chunks: list[Recording], sim: Simulation) -> Recording:
    if len(chunks) == 1:
        rec = chunks[0]
    else:
        last = chunks[-1]
        fields = ("t", "q", "qd", "qdd", "acc", "gyro")
        cat = {k: np.concatenate([getattr(c, k) for c in chunks]) for k in fields}
        rec = Recording(
            joint_names=last.joint_names,
            imu_names=last.imu_names,
            gravity=last.gravity,
            truth_joint_parent=last.truth_joint_parent,
            truth_imu_joint=last.truth_imu_joint,
            extra=dict(last.extra),
            **cat,
        )
    extra = dict(rec.extra)
    # per-chunk RMS (of the body's motion, not of a faulty encoder) pooled over the whole run
    n = np.array([c.n_samples for c in chunks], dtype=np.float64)
    ms = np.array([c.extra["excitation"] ** 2 for c in chunks])
    extra["excitation"] = np.sqrt((n[:, None] * ms).sum(axis=0) / n.sum())
    extra["imu_model"] = np.array(json.dumps(sim.params.to_model(sim.imu_model.name).to_json()))
    extra["robot"] = np.array(sim.source)
    if sim.findings:
        extra["truth_diff"] = np.array(json.dumps(sim.diff.to_json()))
        extra["damage_time"] = np.array(sim.damage_times, dtype=np.float64)
        extra["truth_imu_detached"] = _detached_json(sim.robot.imu_names, sim.robot.truth_arrays()[2])
    return Recording(**{**{f: getattr(rec, f) for f in rec.__dataclass_fields__}, "extra": extra})


def simulate(
    robot: str,
    seconds: float,
    seed: int,
    imu_model: str | ImuModel | None = "mpu6050",
    excitation: str | Excitation = "observable",
    damage: str | Sequence[str | tuple[str, dict[str, Any]]] | None = None,
    rate: float = 100.0,
    sensing: str | SensingOptions | None = "ideal",
) -> Recording:
    """Simulate ``robot`` (catalog name or MJCF/URDF path) for ``seconds``; return the recording.

    ``sensing`` (:mod:`simulators.sensing`: ``ideal``, ``robot`` or options) says how the robot senses
    and stamps its motion. ``ideal`` is today's output at ``rate``: synced, exact joint velocities.
    Anything else simulates the physics at the options' inner rate (1 kHz: what the IMU sees) and
    returns a docs/recording-format.md multi-rate recording; ``rate`` is then unused.

    ``damage`` is one ``KIND[:key=value,...]`` string or a list of them (or ``(kind, kwargs)`` pairs);
    ``at=SECONDS`` injects mid-run (default 0: the whole recording is damaged). The recording's ``extra``
    holds ``excitation`` (RMS joint velocity per joint), ``imu_model`` (the drawn IMU parameters as JSON), and
    with damage ``truth_diff`` (docs/design.md, 'Diff JSON'), ``damage_time`` (s) and ``truth_imu_detached``
    (JSON list of the IMUs that follow no joint). ``truth_*`` describe the body at the end of the run.
    """
    if not seconds > 0:
        raise ValueError("seconds must be > 0")
    opts = resolve_sensing(sensing)
    if not opts.is_ideal:
        if resolve_imu_model(imu_model).rate is not None:
            raise ValueError("an IMU model with its own sample_rate cannot be combined with sensing options")
        rate = opts.inner_rate
    sim = Simulation(robot, seed=seed, imu_model=imu_model, excitation=excitation, rate=rate)
    todo: list[tuple[float, str, dict[str, Any]]] = []
    single = isinstance(damage, str) or (
        isinstance(damage, tuple) and len(damage) == 2 and isinstance(damage[1], dict)
    )
    for d in [damage] if single else list(damage or []):
        kind, kw = parse_damage(d) if isinstance(d, str) else (d[0], dict(d[1]))
        at = float(kw.pop("at", 0.0))
        if not 0.0 <= at < seconds:
            raise ValueError(f"damage time {at} s is outside the run (0..{seconds} s)")
        todo.append((at, kind, kw))
    todo.sort(key=lambda x: x[0])
    total = round(seconds * sim.rate)
    chunks: list[Recording] = []
    for at, kind, kw in todo:
        n = math.ceil(at * sim.rate - 1e-9) - sim._served
        if n > 0:
            chunks.append(sim.advance(n))
        sim.apply_damage(kind, **kw)
    if total - sim._served > 0:
        chunks.append(sim.advance(total - sim._served))
    rec = _concat(chunks, sim)
    if opts.is_ideal:
        return rec
    # a stream of its own, after the four the simulation spawns, so the motion and the IMU noise are
    # those of the same seed's ideal run at the inner rate
    sensing_ss = np.random.SeedSequence(seed).spawn(5)[4]
    return apply_sensing(rec, opts, np.random.default_rng(sensing_ss))
