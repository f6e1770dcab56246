"""The IMU error model: what turns MuJoCo's ideal readings into what a real IMU reports.

MuJoCo's sensor ``noise`` attribute adds nothing, so every error is applied here, composed from the
forward models in :mod:`bodyschema.imu_effects` (the same code the sim-to-real analysis fits).

Effects are applied in this order (ideal -> measured):

1. ``gravity``           the gravity the accelerometer senses (``[0, 0, 0]``: a gravity-free output)
2. ``lever_arm``         accelerometer displaced by ``meters`` (sensor frame) from the nominal point
3. ``mounting_rotation`` sensor frame rotated by ``rotvec`` from the nominal (surface) frame
4. ``gyro_scale``/``acc_scale``  sensitivity matrix: scale (diagonal) and cross-axis terms
5. ``gyro_bias``/``acc_bias``    constant offsets
6. ``time_offset``       samples lag the true motion by ``seconds``
7. ``noise``             white noise (density per √Hz, or std per sample)
8. ``quantization``      converter resolution and full-scale clipping
and ``sample_rate`` (Hz) sets the rate the IMU is sampled at.

JSON format (``load_imu_model``/``save_imu_model``; the sim-to-real analysis writes fitted models in
it)::

    {"format": "bodyhealth-imu-model/1", "name": "mpu6050",
     "effects": [
       {"effect": "gyro_bias",   "params": {"uniform": [0.349, 0.349, 0.349]}},
       {"effect": "acc_scale",   "params": {"matrix": [1.01, 0.99, 1.0]}},
       {"effect": "time_offset", "params": {"seconds": 0.0035}},
       {"effect": "noise",       "params": {"gyro_density": 8.7e-5, "acc_density": 0.0039}},
       {"effect": "acc_bias",    "params": {"vector": [0, 0, 0.1],
                                              "per_imu": {"imu3": {"vector": [0.2, 0, 0]}}}}
     ]}

Parameters per effect (fixed value | random draw per IMU, drawn with the injected generator):

=====================  ======================================  ==========================================
effect                 fixed                                   random
=====================  ======================================  ==========================================
``time_offset``        ``seconds`` (positive = IMU lags)       ``uniform``: half-width, s
``gyro_bias``          ``vector`` (3,), rad/s                  ``uniform``: half-width per axis
``acc_bias``           ``vector`` (3,), m/s²                   ``uniform``: half-width per axis
``gyro_scale``         ``matrix`` (3,3) or gains (3,), 1=ideal ``uniform``: scale half-width (e.g. 0.03);
``acc_scale``                                                  ``cross_axis_uniform``: off-diagonal
``mounting_rotation``  ``rotvec`` (3,), rad                    ``uniform``: half-width per component, rad
``lever_arm``          ``meters`` (3,), sensor frame           ``uniform``: half-width per axis, m
``gravity``            ``vector`` (3,), world m/s²
``noise``              ``gyro_density``/``acc_density`` (unit/√Hz) or ``gyro_std``/``acc_std`` (per sample)
``quantization``       ``gyro_lsb``, ``acc_lsb``, optional ``gyro_range``/``acc_range`` (± full scale)
``sample_rate``        ``hz``
=====================  ======================================  ==========================================

Every effect also takes ``per_imu``: ``{imu_name: {fixed params}}`` overriding the shared value for
those IMUs. ``value`` is read as the effect's main key (``seconds``, ``vector``, ``matrix``, ...).

Example
-------
>>> import numpy as np
>>> model = ImuModel.from_json({"name": "demo", "effects": [
...     {"effect": "gyro_bias", "params": {"vector": [0.1, 0, 0]}}]})
>>> p = model.instantiate(("imu0",), np.random.default_rng(0))
>>> acc, gyro = apply(p, np.arange(3) * 0.01, np.zeros((3, 1, 3)), np.zeros((3, 1, 3)),
...                   rate=100.0, rng=np.random.default_rng(0))
>>> gyro[0, 0].tolist()
[0.1, 0.0, 0.0]
"""

from __future__ import annotations

import functools
import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bodyschema import imu_effects as fx

__all__ = [
    "EFFECTS",
    "FORMAT",
    "PRESETS",
    "ImuModel",
    "ImuParams",
    "ImuStream",
    "apply",
    "distort",
    "finish",
    "load_imu_model",
    "resolve_imu_model",
    "save_imu_model",
]

FORMAT = "bodyhealth-imu-model/1"

#: Effect names (the discrepancy names of docs/design.md, 'Discrepancy JSON', plus ``quantization`` and
#: ``sample_rate``), in the order they are applied.
EFFECTS: tuple[str, ...] = (
    "gravity",
    "lever_arm",
    "mounting_rotation",
    "gyro_scale",
    "acc_scale",
    "gyro_bias",
    "acc_bias",
    "time_offset",
    "noise",
    "quantization",
    "sample_rate",
)

_MAIN_KEY = {
    "time_offset": "seconds",
    "gyro_bias": "vector",
    "acc_bias": "vector",
    "gyro_scale": "matrix",
    "acc_scale": "matrix",
    "mounting_rotation": "rotvec",
    "lever_arm": "meters",
    "gravity": "vector",
    "sample_rate": "hz",
}

_DEG = math.pi / 180.0
_G0 = 9.80665


@dataclass(frozen=True)
class ImuModel:
    """A named list of effects with their parameters (fixed, or ranges drawn per IMU)."""

    name: str = "ideal"
    effects: tuple[tuple[str, dict[str, Any]], ...] = ()

    def __post_init__(self) -> None:
        for eff, params in self.effects:
            if eff not in EFFECTS:
                raise ValueError(f"unknown IMU effect {eff!r}; expected one of {', '.join(EFFECTS)}")
            if not isinstance(params, dict):
                raise ValueError(f"params of effect {eff!r} must be an object")

    # --------------------------------------------------------------------------- JSON
    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ImuModel:
        """Parse the JSON form; ``ValueError`` naming the problem when malformed."""
        try:
            effects = tuple((str(e["effect"]), dict(e.get("params", {}))) for e in data.get("effects", []))
        except (TypeError, KeyError, AttributeError) as err:
            raise ValueError(f"malformed IMU model JSON: {err}") from err
        fmt = data.get("format", FORMAT)
        if fmt != FORMAT:
            raise ValueError(f"unsupported IMU model format {fmt!r} (expected {FORMAT!r})")
        return cls(name=str(data.get("name", "custom")), effects=effects)

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "name": self.name,
            "effects": [{"effect": e, "params": _jsonable(p)} for e, p in self.effects],
        }

    @property
    def rate(self) -> float | None:
        """The sample rate the model asks for (Hz), or None."""
        for e, p in self.effects:
            if e == "sample_rate":
                return float(p.get("hz", p.get("value")))
        return None

    # --------------------------------------------------------------------------- draws
    def instantiate(self, imu_names: tuple[str, ...] | list[str], rng: np.random.Generator) -> ImuParams:
        """Concrete per-IMU parameters: ranges drawn from ``rng`` in a fixed order (effect, then IMU)."""
        names = tuple(imu_names)
        K = len(names)
        p = ImuParams.identity(names)
        for eff, params in self.effects:
            p = _apply_effect_params(p, eff, params, names, K, rng)
        return p


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def _vec3(x: Any, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be a finite scalar or 3-vector, got {x!r}")
    return a


def _matrix(x: Any, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape == (3,):
        a = np.diag(a)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} must be a 3x3 matrix or 3 gains, got {x!r}")
    return a


def _main(params: dict[str, Any], eff: str) -> Any:
    key = _MAIN_KEY.get(eff)
    if key is not None and key in params:
        return params[key]
    return params.get("value")


def _check_sample_rate(p: ImuParams, eff: str, params: dict[str, Any], what: str) -> ImuParams:
    hz = float(_main(params, eff))
    if not hz > 0:
        raise ValueError(f"{what}: hz must be > 0")
    return p


def _set_gravity(p: ImuParams, eff: str, params: dict[str, Any], what: str) -> ImuParams:
    return replace(p, gravity=_vec3(_main(params, eff), what))


def _set_noise(p: ImuParams, eff: str, params: dict[str, Any], what: str) -> ImuParams:
    kind = "std" if ("gyro_std" in params or "acc_std" in params) else "density"
    g = _vec3(params.get(f"gyro_{kind}", 0.0), what)
    a = _vec3(params.get(f"acc_{kind}", 0.0), what)
    if np.any(g < 0) or np.any(a < 0):
        raise ValueError(f"{what}: noise must be >= 0")
    return replace(p, noise_kind=kind, gyro_noise=g, acc_noise=a)


def _set_quantization(p: ImuParams, eff: str, params: dict[str, Any], what: str) -> ImuParams:
    return replace(
        p,
        gyro_lsb=float(params.get("gyro_lsb", 0.0)),
        acc_lsb=float(params.get("acc_lsb", 0.0)),
        gyro_range=float(params.get("gyro_range", math.inf)),
        acc_range=float(params.get("acc_range", math.inf)),
    )


#: Effects shared by all IMUs of a robot: no per-IMU value and no draw.
_SHARED_EFFECTS = {
    "sample_rate": _check_sample_rate,
    "gravity": _set_gravity,
    "noise": _set_noise,
    "quantization": _set_quantization,
}

#: The :class:`ImuParams` field each per-IMU effect fills.
_PER_IMU_FIELD = {
    "time_offset": "time_offset",
    "gyro_bias": "gyro_bias",
    "acc_bias": "acc_bias",
    "gyro_scale": "gyro_matrix",
    "acc_scale": "acc_matrix",
    "mounting_rotation": "rotvec",
    "lever_arm": "lever_arm",
}


def _per_imu_value(src: dict[str, Any], eff: str, what: str, rng: np.random.Generator) -> np.ndarray:
    """One IMU's value of a per-IMU effect: the fixed value in ``src``, else a draw from ``rng``."""
    v = _main(src, eff)
    if v is not None:
        if eff == "time_offset":
            return np.asarray(float(v))
        return _matrix(v, what) if eff.endswith("_scale") else _vec3(v, what)
    if eff.endswith("_scale"):
        s = float(src.get("uniform", 0.0))
        c = float(src.get("cross_axis_uniform", 0.0))
        m = np.diag(1.0 + rng.uniform(-s, s, 3))
        if c:
            m = fx.cross_axis_matrix(np.diag(m), rng.uniform(-c, c, 6))
        return m
    if "uniform" in src:
        h = src["uniform"]
        if eff == "time_offset":
            return np.asarray(rng.uniform(-float(h), float(h)))
        return rng.uniform(-1.0, 1.0, 3) * _vec3(h, what)
    raise ValueError(f"{what} needs {_MAIN_KEY[eff]!r} or 'uniform'")


def _apply_effect_params(
    p: ImuParams, eff: str, params: dict[str, Any], names: tuple[str, ...], K: int, rng: np.random.Generator
) -> ImuParams:
    per_imu = params.get("per_imu", {}) or {}
    unknown = set(per_imu) - set(names)
    if unknown:
        raise ValueError(f"effect {eff!r}: per_imu names unknown IMUs {sorted(unknown)}")
    what = f"effect {eff!r}"
    shared = _SHARED_EFFECTS.get(eff)
    if shared is not None:
        return shared(p, eff, params, what)
    # per-IMU effects: drawn IMU by IMU, in the order of ``names``
    vals = []
    for name in names:
        src = per_imu.get(name)
        vals.append(_per_imu_value(src if src is not None else params, eff, what, rng))
    arr = np.array(vals) if vals else None
    field_name = _PER_IMU_FIELD[eff]
    if arr is None:
        return p
    return replace(p, **{field_name: arr})


@dataclass(frozen=True)
class ImuParams:
    """Concrete per-IMU parameters of one robot's IMUs (K of them)."""

    imu_names: tuple[str, ...]
    time_offset: np.ndarray  # (K,)
    gyro_matrix: np.ndarray  # (K,3,3)
    acc_matrix: np.ndarray
    gyro_bias: np.ndarray  # (K,3)
    acc_bias: np.ndarray
    rotvec: np.ndarray  # (K,3)
    lever_arm: np.ndarray  # (K,3)
    gravity: np.ndarray | None = None
    noise_kind: str = "density"
    gyro_noise: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acc_noise: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_lsb: float = 0.0
    acc_lsb: float = 0.0
    gyro_range: float = math.inf
    acc_range: float = math.inf

    @functools.cached_property
    def flags(self) -> dict[str, bool]:
        """Which effects differ from ideal (so the forward model skips the others)."""
        K = len(self.imu_names)
        eye = np.broadcast_to(np.eye(3), (K, 3, 3))
        return {
            "lever_arm": bool(np.any(self.lever_arm)),
            "rotvec": bool(np.any(self.rotvec)),
            "gyro_matrix": not np.array_equal(self.gyro_matrix, eye),
            "acc_matrix": not np.array_equal(self.acc_matrix, eye),
            "gyro_bias": bool(np.any(self.gyro_bias)),
            "acc_bias": bool(np.any(self.acc_bias)),
            "time_offset": bool(np.any(self.time_offset)),
            "gyro_noise": bool(np.any(self.gyro_noise)),
            "acc_noise": bool(np.any(self.acc_noise)),
        }

    @classmethod
    def identity(cls, imu_names: tuple[str, ...]) -> ImuParams:
        K = len(imu_names)
        eye = np.broadcast_to(np.eye(3), (K, 3, 3)).copy()
        z = np.zeros((K, 3))
        return cls(imu_names, np.zeros(K), eye, eye.copy(), z, z.copy(), z.copy(), z.copy())

    def finishing(self, rate: float) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """Noise std (2, 3), full scale (2,) and resolution (2,) for stacked (gyro, acc), or None
        where the effect is absent; cached per rate (the farm asks every chunk)."""
        cache = self.__dict__.setdefault("_finishing", {})
        if rate not in cache:
            g, a = self.noise_std(rate)
            f = self.flags
            std = np.stack([g, a]) if (f["gyro_noise"] or f["acc_noise"]) else None
            full = (
                np.array([self.gyro_range, self.acc_range])
                if math.isfinite(self.gyro_range) or math.isfinite(self.acc_range)
                else None
            )
            lsb = np.array([self.gyro_lsb, self.acc_lsb]) if self.gyro_lsb > 0 or self.acc_lsb > 0 else None
            cache[rate] = (std, full, lsb)
        return cache[rate]

    def noise_std(self, rate: float) -> tuple[np.ndarray, np.ndarray]:
        """Per-sample white-noise std (gyro, acc) at ``rate`` Hz."""
        if self.noise_kind == "std":
            return self.gyro_noise, self.acc_noise
        r = math.sqrt(rate)
        return self.gyro_noise * r, self.acc_noise * r

    def to_model(self, name: str = "drawn") -> ImuModel:
        """These exact values as a fixed :class:`ImuModel` (``per_imu`` entries), for saving."""
        effs: list[tuple[str, dict[str, Any]]] = []
        if self.gravity is not None:
            effs.append(("gravity", {"vector": self.gravity.tolist()}))

        def per(key: str, values: np.ndarray, default: Any) -> dict[str, Any] | None:
            if np.allclose(values, default):
                return None
            return {
                key: default,
                "per_imu": {n: {key: _jsonable(v)} for n, v in zip(self.imu_names, values, strict=True)},
            }

        eye, z = np.eye(3).tolist(), [0.0, 0.0, 0.0]
        for eff, key, vals, default in (
            ("lever_arm", "meters", self.lever_arm, z),
            ("mounting_rotation", "rotvec", self.rotvec, z),
            ("gyro_scale", "matrix", self.gyro_matrix, eye),
            ("acc_scale", "matrix", self.acc_matrix, eye),
            ("gyro_bias", "vector", self.gyro_bias, z),
            ("acc_bias", "vector", self.acc_bias, z),
            ("time_offset", "seconds", self.time_offset, 0.0),
        ):
            d = per(key, vals, default)
            if d is not None:
                effs.append((eff, d))
        if np.any(self.gyro_noise) or np.any(self.acc_noise):
            k = self.noise_kind
            effs.append(
                ("noise", {f"gyro_{k}": self.gyro_noise.tolist(), f"acc_{k}": self.acc_noise.tolist()})
            )
        if self.gyro_lsb or self.acc_lsb or math.isfinite(self.gyro_range) or math.isfinite(self.acc_range):
            q: dict[str, Any] = {"gyro_lsb": self.gyro_lsb, "acc_lsb": self.acc_lsb}
            if math.isfinite(self.gyro_range):
                q["gyro_range"] = self.gyro_range
            if math.isfinite(self.acc_range):
                q["acc_range"] = self.acc_range
            effs.append(("quantization", q))
        return ImuModel(name=name, effects=tuple(effs))


# ------------------------------------------------------------------------------- forward model
def _pointwise(
    p: ImuParams,
    t: np.ndarray,
    acc: np.ndarray,
    gyro: np.ndarray,
    gyro_dot: np.ndarray | None,
    R: np.ndarray | None,
    world_gravity: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Effects 1-3, which need the rotations / angular accelerations of the same samples."""
    acc = np.asarray(acc, dtype=np.float64)
    gyro = np.asarray(gyro, dtype=np.float64)
    flags = p.flags
    if p.gravity is not None:
        if R is None or R.size == 0 or world_gravity is None:
            raise ValueError("a gravity effect needs the sensor rotations R and the world gravity")
        acc = acc + np.einsum("tkji,j->tki", R, np.asarray(world_gravity) - p.gravity)
    if flags["lever_arm"]:
        wd = gyro_dot if gyro_dot is not None and gyro_dot.size else fx.angular_acceleration(t, gyro)
        acc = fx.lever_arm(acc, gyro, wd, p.lever_arm)
    if flags["rotvec"]:
        acc, gyro = fx.rotate(acc, p.rotvec), fx.rotate(gyro, p.rotvec)
    return acc, gyro


# The remaining effects work on both triads of every IMU stacked as (2, T, K, 3), gyro first: each
# triad is one contiguous block, so per-sensor constants apply as scalars at full numpy speed.
def _sensitivity(p: ImuParams, acc: np.ndarray, gyro: np.ndarray) -> np.ndarray:
    """Effects 4-5 (sensitivity matrix and bias); returns the stacked triads."""
    f = p.flags
    out = np.empty((2, *gyro.shape))
    if f["gyro_matrix"] or f["gyro_bias"]:
        out[0] = fx.affine(
            gyro, p.gyro_matrix if f["gyro_matrix"] else None, p.gyro_bias if f["gyro_bias"] else None
        )
    else:
        out[0] = gyro
    if f["acc_matrix"] or f["acc_bias"]:
        out[1] = fx.affine(
            acc, p.acc_matrix if f["acc_matrix"] else None, p.acc_bias if f["acc_bias"] else None
        )
    else:
        out[1] = acc
    return out


def _shift(p: ImuParams, t: np.ndarray, both: np.ndarray) -> np.ndarray:
    """Effect 6: time offset (per IMU), on stacked triads."""
    if not p.flags["time_offset"] or len(t) < 2:
        return both
    both = both.copy()
    for off in np.unique(p.time_offset):
        if off == 0.0:
            continue
        k = p.time_offset == off
        for s in (0, 1):
            both[s][:, k] = fx.time_shift(t, both[s][:, k], float(off))
    return both


def _finish(p: ImuParams, both: np.ndarray, rate: float, rng: np.random.Generator) -> np.ndarray:
    """Effects 7-8 on stacked triads, in place: white noise, then full-scale clipping and quantization."""
    std, full_scale, lsb = p.finishing(rate)
    _, T, K, _ = both.shape
    if std is not None:
        # one time-major draw: the noise of sample i does not depend on how samples are chunked
        noise = rng.standard_normal((T, 2, K * 3), dtype=np.float32)
        for s in (0, 1):
            both[s].reshape(T, K * 3)[:] += noise[:, s] * np.tile(std[s], K)
    for s in (0, 1):
        x = both[s]
        if full_scale is not None and math.isfinite(full_scale[s]):
            np.clip(x, -full_scale[s], full_scale[s], out=x)
        if lsb is not None and lsb[s] > 0:  # fx.quantize, in place
            x *= 1.0 / lsb[s]
            np.rint(x, out=x)
            x *= lsb[s]
    return both


def distort(
    p: ImuParams,
    t: np.ndarray,
    acc: np.ndarray,
    gyro: np.ndarray,
    *,
    gyro_dot: np.ndarray | None = None,
    R: np.ndarray | None = None,
    world_gravity: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Effects 1-6 (deterministic) on ideal ``acc``/``gyro`` (T,K,3); returns (acc, gyro).

    ``R`` (T,K,3,3) and ``world_gravity`` are needed for a ``gravity`` effect, ``gyro_dot`` (T,K,3)
    for a lever arm (estimated by central differences of ``gyro`` when absent).
    """
    a, g = _pointwise(p, t, acc, gyro, gyro_dot, R, world_gravity)
    both = _shift(p, np.asarray(t, dtype=np.float64), _sensitivity(p, a, g))
    return both[1], both[0]


def finish(
    p: ImuParams, acc: np.ndarray, gyro: np.ndarray, rate: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Effects 7-8: white noise, then quantization and full-scale clipping; returns (acc, gyro)."""
    if all(x is None for x in p.finishing(rate)):
        return acc, gyro
    both = np.stack([np.asarray(gyro, dtype=np.float64), np.asarray(acc, dtype=np.float64)])
    both = _finish(p, both, rate, rng)
    return both[1], both[0]


def apply(
    p: ImuParams,
    t: np.ndarray,
    acc: np.ndarray,
    gyro: np.ndarray,
    *,
    rate: float,
    rng: np.random.Generator,
    gyro_dot: np.ndarray | None = None,
    R: np.ndarray | None = None,
    world_gravity: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The whole forward model on one batch: (acc, gyro) as the IMU reports them."""
    a, g = distort(p, t, acc, gyro, gyro_dot=gyro_dot, R=R, world_gravity=world_gravity)
    return finish(p, a, g, rate, rng)


class ImuStream:
    """The forward model applied chunk by chunk (the farm): keeps the history a time offset needs and
    the state of dead IMUs. A positive offset (lag) is exact across chunks; a negative one (lead) would
    need samples from the future and is edge-held at the end of each chunk.
    """

    def __init__(self, params: ImuParams, rate: float, world_gravity: np.ndarray) -> None:
        self.params = params
        self.rate = float(rate)
        self.world_gravity = np.asarray(world_gravity, dtype=np.float64)
        self.history = math.ceil(float(np.max(np.abs(params.time_offset), initial=0.0)) * rate) + 2
        self._t = np.empty(0)
        self._hist = np.empty((2, 0, len(params.imu_names), 3))
        self.dead: dict[int, str] = {}
        self._last = np.zeros((2, len(params.imu_names), 3))
        self._frozen: dict[int, np.ndarray] = {}

    @property
    def needs_poses(self) -> bool:
        """Whether the physics must provide sensor rotations and angular accelerations."""
        return self.params.gravity is not None or bool(np.any(self.params.lever_arm))

    def kill(self, index: int, mode: str = "frozen") -> None:
        """IMU ``index`` stops: ``frozen`` repeats its last output, ``zero`` outputs zeros."""
        if mode not in ("frozen", "zero"):
            raise ValueError("mode must be 'frozen' or 'zero'")
        self.dead[index] = mode
        self._frozen[index] = self._last[:, index].copy()

    def process(
        self,
        t: np.ndarray,
        acc: np.ndarray,
        gyro: np.ndarray,
        rng: np.random.Generator,
        *,
        gyro_dot: np.ndarray | None = None,
        R: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        T = len(t)
        if T == 0:
            return acc.copy(), gyro.copy()
        # pointwise effects first (they need R / gyro_dot of these very samples) ...
        a, g = _pointwise(p, t, acc, gyro, gyro_dot, R, self.world_gravity)
        both = _sensitivity(p, a, g)
        # ... then the time shift over history + chunk
        if p.flags["time_offset"]:
            ht = np.concatenate([self._t, t])
            hb = np.concatenate([self._hist, both], axis=1)
            both = np.ascontiguousarray(_shift(p, ht, hb)[:, -T:])
            self._t, self._hist = ht[-self.history :], hb[:, -self.history :]
        both = _finish(p, both, self.rate, rng)
        for k, mode in self.dead.items():
            both[:, :, k] = 0.0 if mode == "zero" else self._frozen[k][:, None, :]
        self._last = both[:, -1].copy()
        return both[1], both[0]


# ------------------------------------------------------------------------------- presets and files
def _mpu6050() -> ImuModel:
    """MPU-6050 (datasheet PS-MPU-6000A-00 rev 3.4), ±1000 °/s and ±8 g full scale."""
    return ImuModel(
        name="mpu6050",
        effects=(
            ("gyro_scale", {"uniform": 0.03, "cross_axis_uniform": 0.02}),
            ("acc_scale", {"uniform": 0.03}),
            ("gyro_bias", {"uniform": [20 * _DEG] * 3}),
            ("acc_bias", {"uniform": [0.050 * _G0, 0.050 * _G0, 0.080 * _G0]}),
            ("noise", {"gyro_density": 0.005 * _DEG, "acc_density": 400e-6 * _G0}),
            (
                "quantization",
                {
                    "gyro_lsb": _DEG / 32.8,
                    "acc_lsb": _G0 / 4096,
                    "gyro_range": 1000 * _DEG,
                    "acc_range": 8 * _G0,
                },
            ),
        ),
    )


PRESETS: dict[str, ImuModel] = {"ideal": ImuModel(name="ideal"), "mpu6050": _mpu6050()}


def load_imu_model(path: str | os.PathLike[str]) -> ImuModel:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"{path}: cannot read an IMU model ({err})") from err
    return ImuModel.from_json(data)


def save_imu_model(model: ImuModel, path: str | os.PathLike[str]) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(model.to_json(), indent=2) + "\n", encoding="utf-8")


def resolve_imu_model(spec: str | ImuModel | None) -> ImuModel:
    """A preset name (``ideal``, ``mpu6050``), a JSON file path, or a model: the model."""
    if spec is None:
        return PRESETS["ideal"]
    if isinstance(spec, ImuModel):
        return spec
    if spec in PRESETS:
        return PRESETS[spec]
    if os.path.exists(spec):
        return load_imu_model(spec)
    raise ValueError(f"unknown IMU model {spec!r}: not a preset ({', '.join(PRESETS)}) nor a JSON file")
