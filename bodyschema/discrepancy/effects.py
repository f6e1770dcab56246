"""The effect library: each IMU error effect with its parameters, its prediction and its signature.

An *effect* is one physical reason why a real IMU reads differently from what the ideal simulation of
the same motion says. Every effect here names its parameters (docs/design.md, 'Discrepancy JSON'), their
null value (effect absent), a typical magnitude (used to scale the optimiser), the sensor channel it
touches and the *residual signature* that points to it. The prediction composes the one shared forward
model of each effect, :mod:`bodyschema.imu_effects`, in a fixed order:

1. ``gravity``: specific force ``R^T (a - g)`` with the fitted world gravity ``g``;
2. ``mounting_rotation``: the sensor frame rotated by ``rotvec`` from the body frame;
3. ``lever_arm``: the accelerometer displaced by ``meters`` (sensor frame) from the body origin;
4. ``time_offset``: both channels delayed by ``seconds`` (positive = IMU samples lag the reference);
5. ``gyro_scale``/``gyro_bias`` and ``acc_scale``/``acc_bias``: per-axis gain (``matrix`` holds the
   three gains, 1 = ideal) and offset (``vector``);

The parameter names are those of the simulator's IMU model JSON (:mod:`simulators.imu_model`), and
so is every effect's meaning; only the lever arm is expressed in the rotated sensor frame here (the
simulator applies it before the mounting rotation; the export converts).

``noise`` (white, std per axis) changes no expected reading and is measured apart
(:func:`bodyschema.discrepancy.residuals.noise_std`).

Example
-------
>>> import numpy as np
>>> from bodyschema.rigid_motion import ReferenceMotion
>>> t = np.arange(4) * 0.01
>>> ref = ReferenceMotion(t, np.tile(np.eye(3), (4, 1, 1)), np.zeros((4, 3)), np.zeros((4, 3)),
...                       np.array([0.0, 0.0, -9.81]))
>>> gyro, acc = predict(ref, {"gyro_bias": {"vector": [0.1, 0.0, 0.0]}})
>>> gyro[0].tolist(), acc[0].tolist()
([0.1, 0.0, 0.0], [0.0, 0.0, 9.81])
>>> EFFECTS["lever_arm"].to_params(np.array([0.01, 0.0, 0.02]))
{'meters': [0.01, 0.0, 0.02]}
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bodyschema import imu_effects as fx
from bodyschema.rigid_motion import ReferenceMotion

__all__ = [
    "EFFECTS",
    "EFFECT_NAMES",
    "FITTED_EFFECTS",
    "Effect",
    "Params",
    "nominal",
    "pack",
    "predict",
    "unpack",
]

#: Fitted parameters: effect name -> {parameter name -> value (float or list)}.
Params = dict[str, dict[str, object]]


@dataclass(frozen=True)
class Effect:
    """One error effect: its parameter vector layout, null value, scale and residual signature."""

    name: str
    key: str  # the parameter name in the JSON (params.<key>)
    size: int
    channel: str  # "gyro", "acc" or "both"
    typical: float  # a typical magnitude of one parameter (optimiser scaling)
    signature: str  # the residual pattern that points to this cause
    null: tuple[float, ...]

    def to_params(self, vec: np.ndarray) -> dict[str, object]:
        """Parameter vector -> the JSON-ready dict of this effect."""
        v = np.asarray(vec, dtype=np.float64).reshape(self.size)
        if self.size == 1:
            return {self.key: float(v[0])}
        return {self.key: [float(x) for x in v]}

    def from_params(self, params: Mapping[str, object] | None) -> np.ndarray:
        """The JSON dict of this effect -> its parameter vector (the null vector when absent)."""
        if not params or self.key not in params:
            return np.asarray(self.null, dtype=np.float64)
        v = np.asarray(params[self.key], dtype=np.float64).reshape(-1)
        if v.size != self.size:
            raise ValueError(f"{self.name}.{self.key} needs {self.size} values, got {v.size}")
        return v


_G = (0.0, 0.0, -9.81)

EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect(
            "time_offset",
            "seconds",
            1,
            "both",
            0.005,
            "residual proportional to the derivative of the reading (angular acceleration, jerk)",
            (0.0,),
        ),
        Effect(
            "gyro_bias", "vector", 3, "gyro", 0.01, "constant gyro residual, present at rest", (0.0, 0.0, 0.0)
        ),
        Effect(
            "acc_bias",
            "vector",
            3,
            "acc",
            0.05,
            "constant accelerometer residual in the sensor frame, whatever the orientation",
            (0.0, 0.0, 0.0),
        ),
        Effect(
            "gyro_scale",
            "matrix",
            3,
            "gyro",
            0.01,
            "gyro residual proportional to the angular rate on the same axis",
            (1.0, 1.0, 1.0),
        ),
        Effect(
            "acc_scale",
            "matrix",
            3,
            "acc",
            0.01,
            "accelerometer residual proportional to the reading on the same axis",
            (1.0, 1.0, 1.0),
        ),
        Effect(
            "mounting_rotation",
            "rotvec",
            3,
            "both",
            0.02,
            "residual = reading x axis in both channels: a rate/orientation-dependent cross-axis leak",
            (0.0, 0.0, 0.0),
        ),
        Effect(
            "lever_arm",
            "meters",
            3,
            "acc",
            0.01,
            "accelerometer residual following w x (w x r) + dw/dt x r (grows with the rate squared)",
            (0.0, 0.0, 0.0),
        ),
        Effect(
            "gravity",
            "vector",
            3,
            "acc",
            0.02,
            "accelerometer residual fixed in the world, so it turns with the orientation (R^T dg)",
            _G,
        ),
        Effect(
            "noise",
            "std",
            6,
            "both",
            0.01,
            "white residual above the motion band (std: gyro xyz, then acc xyz)",
            (0.0,) * 6,
        ),
    )
}

#: Effect names in the order the library lists them (docs/design.md, 'Discrepancy JSON').
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)

#: The effects that change the expected reading and so are fitted by least squares.
FITTED_EFFECTS: tuple[str, ...] = tuple(n for n in EFFECT_NAMES if n != "noise")


def nominal(name: str, ref: ReferenceMotion | None = None) -> np.ndarray:
    """The value of effect ``name`` when it is absent: its null, except ``gravity``, whose absence means
    the reference's own gravity (what :func:`predict` uses without it).

    The two agree for a reference built with the standard gravity; a gravity-free reference (the
    sensor networks' Eq. 11 prediction, :mod:`bodyschema.discrepancy.network_gravity`) has none, and
    a fit of the missing gravity must start from there.

    >>> t, z = np.arange(3) * 0.01, np.zeros((3, 3))
    >>> free = ReferenceMotion(t, np.tile(np.eye(3), (3, 1, 1)), z, z, np.zeros(3))
    >>> nominal("gravity").tolist(), nominal("gravity", free).tolist()
    ([0.0, 0.0, -9.81], [0.0, 0.0, 0.0])
    """
    if name == "gravity" and ref is not None:
        return np.asarray(ref.gravity, dtype=np.float64).reshape(3).copy()
    return np.asarray(EFFECTS[name].null, dtype=np.float64)


def pack(
    params: Mapping[str, Mapping[str, object]],
    names: tuple[str, ...] | list[str],
    ref: ReferenceMotion | None = None,
) -> np.ndarray:
    """The concatenated parameter vector of the effects ``names`` (:func:`nominal` values where absent)."""
    parts = [EFFECTS[n].from_params(params[n]) if params.get(n) else nominal(n, ref) for n in names]
    return np.concatenate(parts) if parts else np.zeros(0)


def unpack(vec: np.ndarray, names: tuple[str, ...] | list[str]) -> Params:
    """Inverse of :func:`pack`."""
    out: Params = {}
    i = 0
    for n in names:
        e = EFFECTS[n]
        out[n] = e.to_params(vec[i : i + e.size])
        i += e.size
    if i != np.asarray(vec).size:
        raise ValueError(f"parameter vector has {np.asarray(vec).size} values, the effects need {i}")
    return out


_MEMO: dict[tuple[str, bytes], tuple[ReferenceMotion, np.ndarray]] = {}

#: Values the memo keeps: a fit's finite-difference steps revisit a handful of gravity vectors and
#: rotations; every other value (each step of a gravity or rotation fit) would otherwise stay, with
#: its reference motion, for the life of the process (gigabytes over a benchmark's analyses).
_MEMO_SIZE = 16


def _memo(key: tuple[str, bytes], ref: ReferenceMotion, compute) -> np.ndarray:
    """The value of ``compute()`` for ``key`` on this very ``ref`` (fits re-evaluate the model
    hundreds of times with most effects unchanged; the specific force and the angular acceleration
    only change with gravity and the mounting rotation), from the :data:`_MEMO_SIZE` latest. Returned
    arrays must not be modified."""
    hit = _MEMO.get(key)
    if hit is not None and hit[0] is ref:
        return hit[1]
    value = compute()
    _MEMO.pop(key, None)
    _MEMO[key] = (ref, value)
    while len(_MEMO) > _MEMO_SIZE:
        del _MEMO[next(iter(_MEMO))]  # the oldest (dicts keep insertion order)
    return value


def predict(
    ref: ReferenceMotion, params: Mapping[str, Mapping[str, object]]
) -> tuple[np.ndarray, np.ndarray]:
    """``(gyro, acc)`` (T, 3) the IMU reads for the reference motion under the effects in ``params``.

    Effects absent from ``params`` take their null value; unknown names raise ``ValueError``.
    """
    gyro, acc = predict_rows(ref, params)
    return np.array(gyro, dtype=np.float64), np.array(acc, dtype=np.float64)  # never the memo


#: Stage results a stage cache of :func:`predict_rows` keeps (the base point of a finite-difference
#: Jacobian and the point of the column at hand, for every stage, with room to spare).
_STAGES_SIZE = 24


def _stage(stages: dict | None, key: tuple, compute) -> np.ndarray:
    """``compute()``, kept in ``stages`` under ``key`` (None: not kept), least recently used out."""
    if stages is None:
        return compute()
    hit = stages.pop(key, None)
    if hit is None:
        hit = compute()
    stages[key] = hit  # now the most recently used
    while len(stages) > _STAGES_SIZE:
        del stages[next(iter(stages))]
    return hit


def _key(vec: np.ndarray | None) -> bytes:
    return b"-" if vec is None else vec.tobytes()


def predict_rows(
    ref: ReferenceMotion,
    params: Mapping[str, Mapping[str, object]],
    rows: np.ndarray | None = None,
    stages: dict | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`predict` on the samples ``rows`` (None: all), its stages kept in ``stages``.

    A least-squares fit evaluates the model once per parameter for every finite-difference Jacobian,
    each time with a single parameter changed: a gyro bias only changes the last stage of the gyro,
    a lever arm only the accelerometer's last two. ``stages`` (a dict owned by the caller, used for
    one reference motion and one ``rows``) keeps every stage's result under the values of the
    parameters it depends on, so such an evaluation recomputes only the stages downstream of the
    change. Each stage is computed by exactly the operations :func:`predict` uses, on the same
    inputs, so the result is the same to the last bit; every operation but the angular acceleration
    acts sample by sample, so it is computed on ``rows`` only. Returned arrays may be cached: do not
    modify them.
    """
    unknown = set(params) - set(EFFECTS)
    if unknown:
        raise ValueError(f"unknown effects {sorted(unknown)}; known: {list(EFFECT_NAMES)}")
    if rows is not None and "time_offset" in params:
        raise ValueError("a time offset shifts along the whole grid: predict it on all rows")
    g = EFFECTS["gravity"].from_params(params.get("gravity")) if "gravity" in params else ref.gravity
    ev = _Evaluation(ref, rows, stages, g, g.tobytes())
    gyro, acc, rv = _mounted(ev, params)
    r = None
    if "lever_arm" in params:
        r = EFFECTS["lever_arm"].from_params(params["lever_arm"])
        acc = _levered(ev, gyro, acc, rv, r)
    tau = b"-"
    if "time_offset" in params:
        seconds = float(EFFECTS["time_offset"].from_params(params["time_offset"])[0])
        tau = np.float64(seconds).tobytes()
        both = fx.time_shift(ref.t, np.stack([gyro, acc], axis=1), seconds)
        gyro, acc = both[:, 0], both[:, 1]
    if "gyro_scale" in params or "gyro_bias" in params:
        gs = EFFECTS["gyro_scale"].from_params(params.get("gyro_scale"))
        gb = EFFECTS["gyro_bias"].from_params(params.get("gyro_bias"))
        g0 = gyro
        gyro = ev.stage(("gyro", _key(rv), tau, gs.tobytes(), gb.tobytes()), lambda: fx.affine(g0, gs, gb))
    if "acc_scale" in params or "acc_bias" in params:
        s_ = EFFECTS["acc_scale"].from_params(params.get("acc_scale"))
        b_ = EFFECTS["acc_bias"].from_params(params.get("acc_bias"))
        a0 = acc
        acc = ev.stage(
            ("acc", ev.kg, _key(rv), _key(r), tau, s_.tobytes(), b_.tobytes()),
            lambda: fx.affine(a0, s_, b_),
        )
    return gyro, acc


@dataclass(frozen=True)
class _Evaluation:
    """One :func:`predict_rows` call: the reference, the rows it is on, the caller's stages, gravity."""

    ref: ReferenceMotion
    rows: np.ndarray | None
    stages: dict | None
    g: np.ndarray
    kg: bytes

    def pick(self, x: np.ndarray) -> np.ndarray:
        return x if self.rows is None else x[self.rows]

    def sf(self) -> np.ndarray:
        """The specific force in the sensor frame on the whole grid."""
        ref = self.ref
        return _memo(("sf", self.kg), ref, lambda: fx.specific_force(ref.R, ref.acc_world, self.g))

    def stage(self, key: tuple, compute: Callable[[], Any]) -> Any:
        return _stage(self.stages, key, compute)


def _mounted(
    ev: _Evaluation, params: Mapping[str, Mapping[str, object]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Both triads on the rows, turned by the mounting rotation when there is one (returned too)."""
    omega = ev.ref.omega
    if "mounting_rotation" not in params:
        gyro = ev.stage(("omega",), lambda: ev.pick(omega))
        acc = ev.stage(("sf", ev.kg), lambda: ev.pick(ev.sf()))
        return gyro, acc, None
    rv = EFFECTS["mounting_rotation"].from_params(params["mounting_rotation"])

    def rotated() -> tuple[np.ndarray, np.ndarray]:
        # one call for both triads; each row of the product is that of the whole grid's
        w, f = (
            ev.stage(("omega",), lambda: ev.pick(omega)),
            ev.stage(("sf", ev.kg), lambda: ev.pick(ev.sf())),
        )
        both = fx.rotate(np.concatenate([w, f]), rv)
        return both[: len(w)], both[len(w) :]

    gyro, acc = ev.stage(("rot", ev.kg, rv.tobytes()), rotated)
    return gyro, acc, rv


def _levered(
    ev: _Evaluation, gyro: np.ndarray, acc: np.ndarray, rv: np.ndarray | None, r: np.ndarray
) -> np.ndarray:
    """The specific force at lever arm ``r`` from the link's axis."""
    ref, omega = ev.ref, ev.ref.omega
    key = ("wdot", _key(rv))

    def full_gyro() -> np.ndarray:
        # the angular acceleration differentiates along the whole grid
        return omega if rv is None else fx.rotate(np.concatenate([omega, ev.sf()]), rv)[: len(omega)]

    wdot = ev.stage(
        key, lambda: ev.pick(_memo(key, ref, lambda: fx.angular_acceleration(ref.t, full_gyro())))
    )
    return ev.stage(("lever", ev.kg, _key(rv), r.tobytes()), lambda: fx.lever_arm(acc, gyro, wdot, r))
