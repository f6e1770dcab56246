"""Encoder effects of a robot: what its joint encoders get wrong, seen through the IMUs it carries.

A robot's model (:class:`~bodyschema.forward_kinematics.RobotChain`) and its encoder readings predict
what every IMU reads; where the IMUs disagree in a way the encoders explain, the encoders are wrong.
The effects, each per joint unless said:

* ``encoder_time_offset``: the IMU samples lag the encoder samples by ``seconds`` (one robot-wide
  value: the clock skew between the two streams plus the IMU's filter delay);
* ``encoder_offset``: the encoder reads ``offset`` rad at the link's zero (a zero not calibrated);
* ``encoder_scale``: the encoder reads ``gain`` times the link angle (a wrong gear ratio);
* ``backlash``: a dead band of ``width`` rad between the motor, whose encoder is read, and the link:
  while the joint moves the encoder leads the link by half of it, in the direction of motion.

The encoder model of joint ``j``: ``m = gain θ + offset + width/2 · side(ṁ)``, read ``seconds`` before the
IMU sample with the same stamp; ``side`` is the sign of the encoder's motion, held while it rests.

**What the IMUs are allowed to get wrong.** Each IMU keeps an affine error of its own, fitted in
closed form at every evaluation (variable projection): the gyro a full 3 × 3 matrix and a bias
(scale, cross-axis, and a small mount rotation), the accelerometer a gain per axis and a bias (the
error model of a MEMS IMU such as the MPU-6050; its datasheet's cross-axis terms are gyro terms). The
mount's position and the accelerometer's orientation are taken from the model. So an encoder zero
offset of the *last* joint above an IMU is confounded with that IMU's gyro matrix, and only the
accelerometer's view of gravity tells them apart; an offset of a joint whose axis is vertical, above
every IMU, changes nothing any IMU reads. Such an effect is reported as not observable, never as
absent.

**Evidence.** Both sides are low-passed alike (zero phase, ``cutoff``) and compared on a uniform grid.
Every effect and joint is tested on the gyro and on the accelerometer, given the effects already in
the model (Frisch-Waugh on the finite-difference Jacobian of the projected residual), by the
block-robust Wald test of :func:`bodyschema.discrepancy.evidence.wald`, at the family level ``alpha``
split over the tests of a round (Bonferroni), and must explain at least ``min_gain`` of what the model
leaves of the channel. The most significant effect is added, all named ones are refitted, one named
earlier whose evidence the newcomer explains away leaves for good, and the round repeats until none
passes; every candidate is tried in every round. Named effects get a value, a cluster-robust standard
error over both channels and an interval; an effect not named whose signature is so close to a named
one's that the named one's evidence fails with it in the model is named jointly with it (``"A or B"``,
with the factor that carries the value over); the others get their detection limit (the smallest
change this recording would reveal), or none where no IMU reading changes with them.

Example
-------
A single joint turning about world x, one IMU 0.3 m out; the encoder reads 2 % high:

>>> import numpy as np
>>> from bodyschema.forward_kinematics import RobotChain
>>> chain = RobotChain(("j",), (None,), np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 3)),
...                    ("imu",), (0,), np.eye(3)[None], np.array([[0.0, 0.3, 0.0]]))
>>> t = np.arange(0.0, 40.0, 0.01)
>>> theta = 0.8 * np.sin(1.3 * t) + 0.3 * np.sin(2.9 * t + 1.0)
>>> imu = predict_imus(chain, t, t, theta[:, None], np.zeros(3) + [0.0, 0.0, -9.81])
>>> rng = np.random.default_rng(0)
>>> gyro = imu[:, :, :3] + rng.normal(0.0, 0.005, imu[:, :, :3].shape)
>>> acc = imu[:, :, 3:] + rng.normal(0.0, 0.03, imu[:, :, 3:].shape)
>>> rec = Recording(t=t, joint_names=("j",), q=1.02 * theta[:, None], imu_names=("imu",), acc=acc, gyro=gyro)
>>> rep = analyze_encoders(chain, rec)
>>> rep.names, round(rep.causes[0].value, 3)
(['encoder_scale[j]'], 1.02)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.optimize import least_squares
from scipy.stats import norm

from bodyschema.discrepancy.evidence import CHANNELS, critical_wald, wald
from bodyschema.forward_kinematics import RobotChain
from bodyschema.recording import Recording
from bodyschema.rigid_motion import lowpass

__all__ = [
    "ENCODER_EFFECTS",
    "ENCODER_NULL",
    "EncoderCause",
    "EncoderLimit",
    "EncoderOptions",
    "EncoderReport",
    "analyze_encoders",
    "predict_imus",
]

#: The encoder effects in the order they are listed; the time offset is one value for the robot.
ENCODER_EFFECTS: tuple[str, ...] = ("encoder_time_offset", "encoder_offset", "encoder_scale", "backlash")

#: Per effect: its parameter name, its null value and the finite-difference step of its Jacobian.
_PARAM: dict[str, tuple[str, float, float]] = {
    "encoder_time_offset": ("seconds", 0.0, 1e-3),
    "encoder_offset": ("offset", 0.0, 1e-3),
    "encoder_scale": ("gain", 1.0, 1e-3),
    "backlash": ("width", 0.0, 1e-3),
}


#: Each effect's value when it is absent (an encoder that reads the link's angle, on time).
ENCODER_NULL: dict[str, float] = {e: null for e, (_, null, _) in _PARAM.items()}


@dataclass(frozen=True)
class EncoderOptions:
    """Settings of :func:`analyze_encoders`.

    ``cutoff``: Hz, the low-pass both sides pass (encoder positions are differentiated twice);
    ``rate``: Hz of the uniform comparison grid (None: the IMU's median rate); ``alpha``: family level
    of each round's tests; ``block_s``: the time blocks the tests take as independent; ``edge_s``:
    seconds left out at each end (filter edges, the time shift); ``rest_speed``: rad/s below which an
    encoder counts as resting (backlash keeps its side); ``encoder_cutoff``: Hz, the smoothing of the
    encoder positions before they are differentiated (None: four times ``cutoff``, well above the
    comparison band); ``max_rounds``: effects named at most;
    ``min_gain``: the least share of what the model leaves of a channel's residual energy an effect
    must explain to be named, and ``scale_floor`` (gyro rad/s, accelerometer m/s²) the residual below
    which a channel counts as explained, as in
    :class:`~bodyschema.discrepancy.selection.AnalyzerOptions` (a significant change that explains
    nothing, such as a micro-radian dead band against a simulator's integration error, is not named).
    """

    cutoff: float = 5.0
    rate: float | None = None
    alpha: float = 0.01
    block_s: float = 2.0
    edge_s: float = 1.0
    rest_speed: float = 0.01
    max_rounds: int = 12
    min_gain: float = 0.005
    encoder_cutoff: float | None = None
    scale_floor: tuple[float, float] = (0.002, 0.02)


@dataclass(frozen=True)
class EncoderCause:
    """One named effect: its value (the parameter of :data:`ENCODER_EFFECTS`' meaning), standard error,
    95 % interval, the evidence on the channel that shows it best (given the other named effects) and
    the smallest change of it that channel reveals; ``alternatives``: the effects the recording cannot
    tell from it, each with the factor that turns its change from null into theirs."""

    effect: str
    joint: str | None
    value: float
    stderr: float
    interval: tuple[float, float]
    p_value: float
    channel: str
    detection_limit: float
    alternatives: tuple[tuple[str, float], ...] = ()

    @property
    def own_name(self) -> str:
        return self.effect if self.joint is None else f"{self.effect}[{self.joint}]"

    @property
    def name(self) -> str:
        """The effect's name, or the names of every effect the data cannot tell from it, joined by
        ``or`` (the value is then this effect's; ``alternatives`` map it to the others')."""
        return " or ".join([self.own_name, *(n for n, _ in self.alternatives)])

    def to_json(self) -> dict[str, object]:
        return {
            "effect": self.effect,
            "joint": self.joint,
            "name": self.name,
            "params": {_PARAM[self.effect][0]: self.value},
            "stderr": self.stderr,
            "interval": list(self.interval),
            "p_value": self.p_value,
            "channel": self.channel,
            "detection_limit": self.detection_limit,
            "alternatives": [{"name": n, "factor": f} for n, f in self.alternatives],
        }


@dataclass(frozen=True)
class EncoderLimit:
    """An effect not named: the smallest change of it this recording reveals (``inf``: none would)."""

    effect: str
    joint: str | None
    detection_limit: float

    @property
    def name(self) -> str:
        return self.effect if self.joint is None else f"{self.effect}[{self.joint}]"

    @property
    def observable(self) -> bool:
        return bool(np.isfinite(self.detection_limit))

    def to_json(self) -> dict[str, object]:
        return {
            "effect": self.effect,
            "joint": self.joint,
            "detection_limit": self.detection_limit if self.observable else None,
        }


@dataclass(frozen=True)
class EncoderReport:
    """The named effects in the order found, the others with their detection limits, and the residual
    RMS per channel (normalised units: 1 = the IMUs' own residual without encoder effects)."""

    causes: list[EncoderCause]
    not_named: list[EncoderLimit]
    residual_before: dict[str, float]
    residual_after: dict[str, float]
    meta: dict[str, object] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.causes]

    def cause(self, name: str) -> EncoderCause | None:
        """The cause named ``name``, alone or jointly with others."""
        return next((c for c in self.causes if name in c.name.split(" or ")), None)

    def limit(self, name: str) -> EncoderLimit | None:
        return next((x for x in self.not_named if x.name == name), None)

    def to_json(self) -> dict[str, object]:
        return {
            "causes": [c.to_json() for c in self.causes],
            "not_named": [x.to_json() for x in self.not_named],
            "residual_before": self.residual_before,
            "residual_after": self.residual_after,
            "meta": self.meta,
        }

    def summary(self) -> list[str]:
        """One line per effect: named with its value and interval, or its detection limit."""
        out = []
        for c in self.causes:
            unit = _UNIT[c.effect]
            lo, hi = c.interval
            line = f"{c.own_name} = {c.value:.6g}{unit} ({lo:.6g} .. {hi:.6g}), p={c.p_value:.2g}"
            if c.alternatives:
                others = ", ".join(n for n, _ in c.alternatives)
                line = (
                    f"{c.name}: the recording cannot tell them apart; {line} (or {others} in proportion); "
                    "moving each joint alone while the links between them tilt against gravity would"
                )
            out.append(line)
        for x in self.not_named:
            why = (
                f"below {x.detection_limit:.3g}{_UNIT[x.effect]} here"
                if x.observable
                else "no IMU reading changes with it here"
            )
            out.append(f"{x.name}: not named, {why}")
        return out


#: The unit each effect's value is printed with.
_UNIT = {"encoder_time_offset": " s", "encoder_offset": " rad", "encoder_scale": "", "backlash": " rad"}


# ---------------------------------------------------------------------------- the forward model
def _side(t_q: np.ndarray, m: np.ndarray, rest_speed: float, cutoff: float) -> np.ndarray:
    """(T_q, N) the side of each encoder's dead band: the sign of its motion, held while it rests
    (+1 before it first moves)."""
    rate = float(1.0 / np.median(np.diff(t_q)))
    v = np.gradient(lowpass(m, rate, min(cutoff, 0.4 * rate)), t_q, axis=0)
    moving = np.abs(v) > rest_speed
    idx = np.where(moving, np.arange(len(t_q))[:, None], -1)
    np.maximum.accumulate(idx, axis=0, out=idx)
    sign = np.sign(v)
    picked = np.take_along_axis(sign, np.maximum(idx, 0), axis=0)
    return np.where(idx >= 0, picked, 1.0)


def predict_imus(
    chain: RobotChain,
    t: np.ndarray,
    t_q: np.ndarray,
    theta: np.ndarray,
    gravity: np.ndarray,
    cutoff: float | None = None,
) -> np.ndarray:
    """(T, K, 6) gyro then accelerometer readings the model predicts at the uniform stamps ``t``, from
    link angles ``theta`` (T_q, N) at stamps ``t_q``, low-passed at ``cutoff`` Hz (None: not).

    The angles are differentiated as given (smooth them first); the low-pass acts once, on the
    readings, as it acts on the measured ones: filtering the angles as well would attenuate the
    prediction twice (a Butterworth filter of order 4 at 5 Hz takes 1.7 % off a 3 Hz motion per
    zero-phase pass, which reads as a gear ratio).
    """
    rate = float(1.0 / np.median(np.diff(t)))
    # Derivatives from quintic splines: central differences at 100 Hz take 3 % off the acceleration
    # of a 5 Hz motion (sinc²), which reads as gear ratios and zero offsets.
    spl = make_interp_spline(t_q, theta, k=5, axis=0)
    R, p, omega = chain.motion(spl(t), spl(t, 1))
    acc_world = make_interp_spline(t, p, k=5, axis=0)(t, 2)
    f = np.einsum("tkba,tkb->tka", R, acc_world - np.asarray(gravity, dtype=np.float64))
    out = np.concatenate([omega, f], axis=2)
    return lowpass(out, rate, cutoff)


@dataclass(frozen=True)
class _Candidate:
    effect: str
    joint: int | None


class _Problem:
    """The data on the comparison grid and the projected, normalised residual of a parameter set."""

    def __init__(
        self,
        chain: RobotChain,
        t_q: np.ndarray,
        q: np.ndarray,
        t: np.ndarray,
        meas: np.ndarray,
        gravity: np.ndarray,
        opts: EncoderOptions,
    ) -> None:
        """``meas`` (T, K, 6): gyro then accelerometer readings at the IMU stamps ``t``."""
        self.chain, self.opts, self.gravity = chain, opts, gravity
        rate = opts.rate or float(1.0 / np.median(np.diff(t)))
        lo, hi = max(t[0], t_q[0]) + opts.edge_s, min(t[-1], t_q[-1]) - opts.edge_s
        if hi - lo < 10 * opts.block_s:
            need = 10 * opts.block_s + 2 * opts.edge_s
            raise ValueError(
                f"the IMU and encoder streams overlap by {hi - lo + 2 * opts.edge_s:.1f} s; too short: the "
                f"tests need ten {opts.block_s:g} s blocks and {opts.edge_s:g} s at each end ({need:g} s)"
            )
        self.rate = rate
        # the comparison grid reaches edge_s beyond the index on both sides, for the filters
        self.t = np.arange(lo - opts.edge_s, hi + opts.edge_s, 1.0 / rate)
        self.index = np.flatnonzero((self.t >= lo) & (self.t <= hi))
        # Onto the grid by cubic splines: linear interpolation between samples is a low-pass whose
        # gain depends on where the grid falls between them (up to 0.4 % off a 3 Hz motion at 100 Hz).
        grid = make_interp_spline(t, meas.reshape(len(t), -1), k=3, axis=0)(self.t)
        self.meas = lowpass(grid.reshape(len(self.t), meas.shape[1], 6), rate, opts.cutoff)[self.index]
        # The encoders go onto a uniform grid of their own rate (their stamps jitter: a spline through
        # jittered stamps turns the jitter into rate noise) and are smoothed once there, well above
        # the comparison band (their quantization would otherwise be differentiated twice); the
        # model is linear in them and in the side.
        rate_q = float(1.0 / np.median(np.diff(t_q)))
        self.t_q = np.arange(t_q[0], t_q[-1], 1.0 / rate_q)
        q_u = make_interp_spline(t_q, q, k=3, axis=0)(self.t_q)
        pre = min(opts.encoder_cutoff or 4.0 * opts.cutoff, 0.4 * rate_q)
        self.q = lowpass(q_u, rate_q, pre)
        self.side = lowpass(_side(self.t_q, q_u, opts.rest_speed, opts.cutoff), rate_q, pre)
        self.scale = np.ones((meas.shape[1], 2))
        self.candidates = [_Candidate("encoder_time_offset", None)] + [
            _Candidate(e, j) for e in ENCODER_EFFECTS[1:] for j in range(len(chain.joint_names))
        ]
        self.null = np.array([ENCODER_NULL[c.effect] for c in self.candidates])
        self.step = np.array([_PARAM[c.effect][2] for c in self.candidates])
        # Every IMU's prediction, filtered and fitted on its own, depends only on the joints from the
        # root to its link: a change of a joint's encoder moves the IMUs below it and leaves every
        # other IMU's residual exactly as it was. Per joint: those IMUs (None: all) and their chain.
        self._below: dict[int, tuple[np.ndarray, RobotChain] | None] = {}
        for j in range(len(chain.joint_names)):
            ks = np.array([k for k in range(len(chain.imu_names)) if j in chain.path(k)], dtype=int)
            sub = (
                chain.subset([chain.imu_names[k] for k in ks])
                if 0 < ks.size < len(chain.imu_names)
                else chain
            )
            self._below[j] = None if ks.size == len(chain.imu_names) else (ks, sub)
        self._residuals: dict[bytes, np.ndarray] = {}
        self._last_jacobian: tuple[bytes, list[int], np.ndarray] | None = None

    @property
    def scale(self) -> np.ndarray:
        """(K, 2) each IMU's gyro and accelerometer normalisation."""
        return self._scale

    @scale.setter
    def scale(self, value: np.ndarray) -> None:
        self._scale = value
        # the residuals kept are in the units of the old scale
        self._residuals = {}
        self._last_jacobian = None

    def theta(self, x: np.ndarray) -> tuple[np.ndarray, float]:
        """Link angles (T_q, N) and the time offset of the full parameter vector ``x``."""
        n = len(self.chain.joint_names)
        tau, off, gain, width = x[0], x[1 : 1 + n], x[1 + n : 1 + 2 * n], x[1 + 2 * n :]
        return (self.q - off - 0.5 * width * self.side) / gain, float(tau)

    def predicted(self, x: np.ndarray, imus: tuple[np.ndarray, RobotChain] | None = None) -> np.ndarray:
        """(T, K, 6) the prediction at the parameters ``x``, of the IMUs ``imus`` (indices and their
        chain; None: all)."""
        theta, tau = self.theta(x)
        chain = self.chain if imus is None else imus[1]
        pred = predict_imus(chain, self.t, self.t_q + tau, theta, self.gravity, self.opts.cutoff)
        return pred[self.index]

    def residual(self, x: np.ndarray) -> np.ndarray:
        """(T, K, 6) measured minus predicted, each IMU's affine errors fitted out, normalised."""
        # A fit evaluates its accepted points again for their Jacobian, and the selection asks for the
        # Jacobian at the same point for its tests, the member tests and the final report.
        key = x.tobytes()
        hit = self._residuals.pop(key, None)
        if hit is None:
            hit = self._residual(x)
        self._residuals[key] = hit
        while len(self._residuals) > 3:
            del self._residuals[next(iter(self._residuals))]
        return hit.copy()

    def _residual(self, x: np.ndarray, imus: tuple[np.ndarray, RobotChain] | None = None) -> np.ndarray:
        """:meth:`residual` of the IMUs ``imus`` (indices and their chain; None: all), in that order."""
        pred = self.predicted(x, imus)
        ks = range(pred.shape[1]) if imus is None else imus[0]
        out = np.empty_like(pred)
        one = np.ones((len(pred), 1))
        for i, k in enumerate(ks):
            G = np.hstack([pred[:, i, :3], one])  # gyro: full matrix and bias
            coef, *_ = np.linalg.lstsq(G, self.meas[:, k, :3], rcond=None)
            out[:, i, :3] = (self.meas[:, k, :3] - G @ coef) / self.scale[k, 0]
            for c in range(3, 6):  # accelerometer: gain and bias per axis
                A = np.hstack([pred[:, i, c : c + 1], one])
                coef, *_ = np.linalg.lstsq(A, self.meas[:, k, c], rcond=None)
                out[:, i, c] = (self.meas[:, k, c] - A @ coef) / self.scale[k, 1]
        return out

    def jacobian(self, x: np.ndarray, which: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """``(J (T, K, 6, p), residual (T, K, 6))`` for the candidates ``which`` (central differences).

        A joint's candidate moves only the IMUs below the joint; the other IMUs' columns are exactly
        zero (both sides of the difference are the same numbers) and are not computed. Columns of
        the last Jacobian at the same ``x`` are taken over: the selection asks for the named
        effects' columns after a refit, again for the next round's tests and for the report.
        """
        key = x.tobytes()
        r0 = self.residual(x)
        J = np.zeros((*r0.shape, len(which)))
        last = self._last_jacobian if self._last_jacobian and self._last_jacobian[0] == key else None
        for i, c in enumerate(which):
            if last is not None and c in last[1]:
                J[..., i] = last[2][..., last[1].index(c)]
                continue
            h = self.step[c]
            xp, xm = x.copy(), x.copy()
            xp[c] += h
            xm[c] -= h
            joint = self.candidates[c].joint
            imus = None if joint is None else self._below[joint]
            if imus is None:
                J[..., i] = (self._residual(xp) - self._residual(xm)) / (2 * h)
            elif imus[0].size:
                J[..., i][:, imus[0]] = (self._residual(xp, imus) - self._residual(xm, imus)) / (2 * h)
        self._last_jacobian = (key, list(which), J)
        return J, r0


def _blocks(n: int, rate: float, block_s: float) -> list[np.ndarray]:
    return np.array_split(np.arange(n), max(2, round(n / rate / block_s)))


def _channel(a: np.ndarray, ch: str) -> np.ndarray:
    """The rows of channel ``ch`` of (T, K, 6, ...) as (T, rows, ...)."""
    sl = CHANNELS[ch]
    sub = a[:, :, sl]
    return sub.reshape(sub.shape[0], -1, *sub.shape[3:])


def analyze_encoders(
    chain: RobotChain, rec: Recording, options: EncoderOptions | None = None
) -> EncoderReport:
    """Name the encoder effects the IMUs of ``rec`` reveal against the robot ``chain`` (see the module
    docstring).

    Every joint of ``chain`` must be in the recording (an angle not recorded moves the IMUs in a way
    nothing predicts); the IMUs compared are those of the recording that ``chain`` carries. The IMU
    clock may be offset from the encoders' (``t`` against ``t_q`` in a multi-rate recording).
    """
    opts = options or EncoderOptions()
    prob, chain, imus = _problem(chain, rec, opts)
    x = prob.null.copy()
    r = prob.residual(x)
    prob.scale = np.stack(
        [np.sqrt(np.mean(r[:, :, :3] ** 2, axis=(0, 2))), np.sqrt(np.mean(r[:, :, 3:] ** 2, axis=(0, 2)))],
        axis=1,
    )
    r = prob.residual(x)
    floor = tuple(float(np.mean((f / prob.scale[:, i]) ** 2)) for i, f in enumerate(opts.scale_floor))
    before = {ch: float(np.sqrt(np.mean(_channel(r, ch) ** 2))) for ch in ("gyro", "acc")}
    blocks = _blocks(len(prob.index), prob.rate, opts.block_s)
    x, model, limits = _select(prob, x, blocks, opts, floor)
    causes, after = _final(prob, x, model, blocks, opts, floor)
    joint_names = {n for c in causes for n, _ in c.alternatives}
    not_named = [
        EncoderLimit(
            prob.candidates[c].effect, _joint(chain, prob.candidates[c]), float(limits.get(c, np.inf))
        )
        for c in range(len(prob.candidates))
        if c not in model and _name(prob, c) not in joint_names
    ]
    meta = {
        "samples_used": len(prob.index),
        "rate_hz": prob.rate,
        "cutoff_hz": opts.cutoff,
        "imu_names": imus,
    }
    return EncoderReport(causes, not_named, before, after, meta)


def _problem(
    chain: RobotChain, rec: Recording, opts: EncoderOptions
) -> tuple[_Problem, RobotChain, list[str]]:
    """The fitting problem of ``rec`` against ``chain``, the chain cut to the recording's IMUs, and those
    IMUs; raises when the recording cannot be compared with the chain."""
    if rec.q is None:
        raise ValueError("the recording has no joint positions q")
    missing = [j for j in chain.joint_names if j not in rec.joint_names]
    if missing:
        raise ValueError(f"joints {missing} of the model are not in the recording ({list(rec.joint_names)})")
    imus = [k for k in rec.imu_names if k in chain.imu_names]
    if not imus:
        raise ValueError(f"none of the recording's IMUs {list(rec.imu_names)} is on the model")
    chain = chain.subset(imus)
    k = [rec.imu_names.index(n) for n in imus]
    meas = np.concatenate([rec.gyro[:, k], rec.acc[:, k]], axis=2)
    if not np.all(np.isfinite(meas)):
        raise ValueError("the IMU readings must be finite; fill or cut the gaps first")
    q = rec.q[:, [rec.joint_names.index(j) for j in chain.joint_names]]
    prob = _Problem(chain, rec.encoder_t, q, rec.t, meas, np.asarray(rec.gravity, dtype=np.float64), opts)
    return prob, chain, imus


def _select(
    prob: _Problem, x: np.ndarray, blocks: list[np.ndarray], opts: EncoderOptions, floor: tuple[float, float]
) -> tuple[np.ndarray, list[int], dict[int, float]]:
    """Forward selection: each round adds the candidate that passes its test by most and drops the ones
    it explains away. Returns the parameters, the candidates named and each candidate's detection
    limit in the last round."""
    model: list[int] = []
    dropped: set[int] = set()
    limits: dict[int, float] = {}
    for _ in range(opts.max_rounds):
        rest = [c for c in range(len(prob.candidates)) if c not in model]
        J, r = prob.jacobian(x, model + rest)
        tests = _round_tests(J, r, len(model), rest, blocks, opts, floor)
        limits = {c: min((ev.detection_limit for ev, _ in evs), default=np.inf) for c, evs in tests.items()}
        passed = [
            (ev.statistic / critical_wald(ev.alpha, 1, ev.clusters), c)
            for c, evs in tests.items()
            for ev, enough in evs
            if ev.p_value < ev.alpha and enough and c not in dropped
        ]
        if not passed:
            break
        model.append(max(passed)[1])
        x = _refit(prob, x, model)
        # An effect named earlier that the newcomer explains away leaves (a partner first named in its
        # place); it is not tried again.
        J, r = prob.jacobian(x, model)
        weak = [
            c
            for c, evs in _member_tests(prob, J, r, x, model, blocks, opts, floor).items()
            if not _holds(evs)
        ]
        if weak:
            model = [c for c in model if c not in weak]
            dropped.update(weak)
            x[weak] = prob.null[weak]
            x = _refit(prob, x, model) if model else x
    return x, model, limits


def _joint(chain: RobotChain, c: _Candidate) -> str | None:
    return None if c.joint is None else chain.joint_names[c.joint]


def _round_tests(
    J: np.ndarray,
    r: np.ndarray,
    n_model: int,
    rest: list[int],
    blocks: list[np.ndarray],
    opts: EncoderOptions,
    floor: tuple[float, float],
) -> dict[int, list]:
    """Each candidate of ``rest`` tested on each channel it moves, given the first ``n_model`` columns
    of ``J`` (the model), at ``alpha`` split over the tests made; ``floor``: each channel's energy
    floor (normalised units)."""
    cases = []
    for ch, fl in zip(("gyro", "acc"), floor, strict=True):
        Jc, y = _channel(J, ch), _channel(r, ch)
        rows = Jc.shape[1]
        Jc = Jc.reshape(-1, J.shape[-1])
        y = y.reshape(-1)
        if n_model:
            Q, _ = np.linalg.qr(Jc[:, :n_model])
            y = y - Q @ (Q.T @ y)
        for i, c in enumerate(rest):
            X = Jc[:, n_model + i : n_model + i + 1]
            if n_model:
                X = X - Q @ (Q.T @ X)
            if np.sqrt(np.mean(X**2)) < 1e-6 * max(1.0, float(np.sqrt(np.mean(y**2)))):
                continue  # this channel does not see the effect with this motion
            cases.append((c, ch, X, y, rows, opts.min_gain * max(float(np.mean(y**2)), fl)))
    level = opts.alpha / max(1, len(cases))
    out: dict[int, list] = {c: [] for c in rest}
    for c, ch, X, y, rows, least in cases:
        ev = wald(str(c), ch, X, y, rows, blocks, level, least)
        gain = ev.estimate[0] ** 2 * float(X[:, 0] @ X[:, 0]) / len(y)
        out[c].append((ev, gain >= least))
    return out


def _refit(prob: _Problem, x: np.ndarray, model: list[int]) -> np.ndarray:
    """Least squares over the named effects' parameters, the rest at their values in ``x``."""
    sel = np.array(model)

    def full(z: np.ndarray) -> np.ndarray:
        out = x.copy()
        out[sel] = z
        return out

    def fun(z: np.ndarray) -> np.ndarray:
        return prob.residual(full(z)).reshape(-1)

    def jac(z: np.ndarray) -> np.ndarray:
        J, _ = prob.jacobian(full(z), model)
        return J.reshape(-1, len(model)).copy()  # the problem keeps J for the next request

    res = least_squares(fun, x[sel], jac=jac, x_scale=prob.step[sel] * 10, method="trf", max_nfev=20)
    return full(res.x)


def _holds(evs: list) -> bool:
    """Whether an effect's evidence passes on some channel: significant and explaining enough."""
    return any(ev.p_value < ev.alpha and enough for ev, enough in evs)


def _member_tests(
    prob: _Problem,
    J: np.ndarray,
    r: np.ndarray,
    x: np.ndarray,
    model: list[int],
    blocks: list[np.ndarray],
    opts: EncoderOptions,
    floor: tuple[float, float],
    extra: np.ndarray | None = None,
) -> dict[int, list]:
    """Each named effect tested given the others (and the columns ``extra`` (T, K, 6, e), if any):
    its own fitted change added back to the residual (linearised), the others' columns projected out.
    ``J``: the Jacobian over ``model`` at ``x``, ``r`` the residual there."""
    out = {}
    for i, c in enumerate(model):
        order = [k for k in range(len(model)) if k != i]
        cols = J[..., order]
        if extra is not None:
            cols = np.concatenate([cols, extra], axis=-1)
        y = r + J[..., i] * (x[c] - prob.null[c])
        out[c] = _round_tests(
            np.concatenate([cols, J[..., i : i + 1]], axis=-1), y, cols.shape[-1], [c], blocks, opts, floor
        )[c]
    return out


def _final(
    prob: _Problem,
    x: np.ndarray,
    model: list[int],
    blocks: list[np.ndarray],
    opts: EncoderOptions,
    floor: tuple[float, float],
) -> tuple[list[EncoderCause], dict[str, float]]:
    """The named effects with their cluster-robust standard errors (both channels, all named effects
    free), the p-value of each given the others, and the effects the data cannot tell from it; the
    residual RMS after them."""
    rest = [c for c in range(len(prob.candidates)) if c not in model]
    Jall, r = prob.jacobian(x, model + rest)
    J = Jall[..., : len(model)]
    after = {ch: float(np.sqrt(np.mean(_channel(r, ch) ** 2))) for ch in ("gyro", "acc")}
    if not model:
        return [], after
    X = J.reshape(len(r), -1, len(model))
    u = r.reshape(len(r), -1)
    inv = np.linalg.pinv(np.einsum("trk,trl->kl", X, X))
    scores = np.stack([np.einsum("trk,tr->k", X[b], u[b]) for b in blocks])
    G = len(blocks)
    V = inv @ (scores.T @ scores) @ inv * G / max(G - 1, 1)
    se = np.sqrt(np.clip(np.diag(V), 0.0, None))
    z = norm.isf(0.025)
    tests = _member_tests(prob, J, r, x, model, blocks, opts, floor)
    causes = []
    for i, c in enumerate(model):
        cand = prob.candidates[c]
        best = min((ev for ev, _ in tests[c]), key=lambda ev: ev.p_value)
        alternatives = _partners(prob, Jall, r, x, model, i, rest, blocks, opts, floor)
        v = float(x[c])
        causes.append(
            EncoderCause(
                cand.effect,
                _joint(prob.chain, cand),
                v,
                float(se[i]),
                (v - z * float(se[i]), v + z * float(se[i])),
                float(best.p_value),
                best.channel,
                float(best.detection_limit),
                alternatives,
            )
        )
    return causes, after


def _partners(
    prob: _Problem,
    Jall: np.ndarray,
    r: np.ndarray,
    x: np.ndarray,
    model: list[int],
    i: int,
    rest: list[int],
    blocks: list[np.ndarray],
    opts: EncoderOptions,
    floor: tuple[float, float],
) -> tuple[tuple[str, float], ...]:
    """The effects not named whose signature is so close to named effect ``model[i]``'s (the other
    named ones projected out) that its evidence fails once either is in the model: the data cannot
    tell them apart, so they are named jointly. Each with the factor that turns the named effect's
    change into the partner's: ``partner change = factor * named change``."""
    n = len(model)
    others = [k for k in range(n) if k != i]
    X = Jall.reshape(-1, Jall.shape[-1])
    if others:
        Q, _ = np.linalg.qr(X[:, others])
        X = X - Q @ (Q.T @ X)
    xc = X[:, i]
    out = []
    for m, c in enumerate(rest):
        xp = X[:, n + m]
        norm2 = float(xp @ xp)
        if norm2 <= 0.0 or float(xc @ xc) <= 0.0:
            continue
        rho = abs(float(xc @ xp)) / np.sqrt(norm2 * float(xc @ xc))
        if rho < 0.5:
            continue  # far apart: the partner would not move the named value much (and is cheap to skip)
        J = Jall[..., :n]
        evs = _member_tests(prob, J, r, x, model, blocks, opts, floor, extra=Jall[..., n + m : n + m + 1])[
            model[i]
        ]
        if not _holds(evs):
            out.append((_name(prob, c), float(xc @ xc) / float(xc @ xp)))
    return tuple(out)


def _name(prob: _Problem, c: int) -> str:
    cand = prob.candidates[c]
    return cand.effect if cand.joint is None else f"{cand.effect}[{prob.chain.joint_names[cand.joint]}]"
