"""Sensor faults injected into a recording: the truth the health checks are measured against.

Each fault is a pure function of a :class:`~bodyschema.recording.Recording` (a new one comes back,
the input is never touched) and a :class:`Fault`, written as ``kind:key=value,...``:

* ``encoder_frozen:joint=J[,at=T]`` — the encoder repeats its last reading before ``T``; its
  velocities (``qd``, ``qdd`` when the recording has them) read 0.
* ``encoder_offset:joint=J,deg=D[,at=T]`` — the reading is ``D`` degrees off (a slipped magnet or a
  re-homed axis); velocities unchanged.
* ``encoder_sign:joint=J[,at=T]`` — the reading is sign-flipped (a wiring or configuration error), and
  with it the velocities the drive derives from it.
* ``imu_rotated:imu=I,deg=D[,axis=x|y|z][,at=T]`` — the IMU turned on its mount by ``D`` degrees about
  its own ``axis`` (default ``x``): both accelerometer and gyro readings become ``R r``.
* ``imu_silent:imu=I,seconds=S[,at=T]`` — the IMU stops updating for ``S`` seconds. A recording file
  holds no NaN (the loader refuses it), so silence appears as a stuck sensor does on a bus: the last
  reading before ``T`` repeated on all six axes until the stream resumes.

``at`` is seconds from the recording's first stamp (default 0: the whole recording);
``at=random`` draws it uniformly from the first 80 % of the recording with the seeded generator.
Every fault applied is appended to ``extra["injected_faults"]`` (a JSON list of
``{"kind", "params", "start_s", "stop_s"}``) so tests and benchmarks know the truth; estimators never
read it.

Example
-------
>>> import numpy as np
>>> t = np.arange(100) * 0.01
>>> rec = Recording(t=t, joint_names=("j1",), q=np.c_[np.sin(t)], imu_names=("imu0",),
...                 acc=np.zeros((100, 1, 3)) + [0, 0, 9.81], gyro=np.zeros((100, 1, 3)))
>>> out = inject(rec, parse_fault("encoder_offset:joint=j1,deg=2,at=0.5"))
>>> round(float(np.degrees(out.q[60, 0] - rec.q[60, 0])), 6), float(out.q[10, 0] - rec.q[10, 0])
(2.0, 0.0)
>>> injected_faults(out)[0]["kind"]
'encoder_offset'
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bodyschema.forward_kinematics import axis_rotations
from bodyschema.recording import Recording

__all__ = ["FAULT_KINDS", "Fault", "FaultError", "inject", "inject_all", "injected_faults", "parse_fault"]

#: Fault kind -> (required keys, optional keys).
FAULT_KINDS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "encoder_frozen": (("joint",), ("at",)),
    "encoder_offset": (("joint", "deg"), ("at",)),
    "encoder_sign": (("joint",), ("at",)),
    "imu_rotated": (("imu", "deg"), ("axis", "at")),
    "imu_silent": (("imu", "seconds"), ("at",)),
}
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


class FaultError(ValueError):
    """A fault specification that names an unknown kind, key, joint or IMU, or a bad value."""


@dataclass(frozen=True)
class Fault:
    """One fault: ``kind`` in :data:`FAULT_KINDS` and its parameters as given (strings)."""

    kind: str
    params: tuple[tuple[str, str], ...]

    def get(self, key: str, default: str | None = None) -> str | None:
        return dict(self.params).get(key, default)

    def number(self, key: str, default: float | None = None) -> float:
        v = self.get(key)
        if v is None:
            if default is None:
                raise FaultError(f"{self.kind}: {key}= is required")
            return default
        try:
            x = float(v)
        except ValueError:
            raise FaultError(f"{self.kind}: {key}={v!r} is not a number") from None
        if not np.isfinite(x):
            raise FaultError(f"{self.kind}: {key}={v!r} is not finite")
        return x


def parse_fault(spec: str) -> Fault:
    """``kind:key=value,...`` -> :class:`Fault`, refusing unknown kinds and keys and missing ones.

    >>> parse_fault("imu_rotated:imu=base,deg=2,axis=y")
    Fault(kind='imu_rotated', params=(('imu', 'base'), ('deg', '2'), ('axis', 'y')))
    """
    kind, _, rest = spec.strip().partition(":")
    if kind not in FAULT_KINDS:
        raise FaultError(f"unknown fault kind {kind!r}; expected one of {', '.join(FAULT_KINDS)}")
    need, opt = FAULT_KINDS[kind]
    params: list[tuple[str, str]] = []
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq or not val.strip():
            raise FaultError(f"{kind}: {item!r} is not key=value")
        if key.strip() not in need + opt:
            raise FaultError(f"{kind}: unknown key {key.strip()!r}; expected {', '.join(need + opt)}")
        params.append((key.strip(), val.strip()))
    keys = [k for k, _ in params]
    missing = [k for k in need if k not in keys]
    if missing:
        raise FaultError(f"{kind}: missing {', '.join(k + '=' for k in missing)}")
    if len(set(keys)) != len(keys):
        raise FaultError(f"{kind}: a key is given twice")
    if kind == "imu_rotated" and dict(params).get("axis", "x") not in _AXES:
        raise FaultError(f"{kind}: axis must be x, y or z")
    fault = Fault(kind, tuple(params))
    for key in ("deg", "seconds", "at"):
        if key in keys and not (key == "at" and dict(params)[key] == "random"):
            fault.number(key)  # refuses a value that is not a finite number, now rather than later
    return fault


def _start(rec: Recording, fault: Fault, rng: np.random.Generator) -> float:
    """The fault's start on the recording's clock (seconds since its first stamp -> stamp)."""
    t0 = float(min(rec.t[0], rec.encoder_t[0]))
    at = fault.get("at", "0")
    if at == "random":
        return t0 + float(rng.uniform(0.0, 0.8 * rec.duration))
    x = fault.number("at", 0.0)
    if x < 0:
        raise FaultError(f"{fault.kind}: at={at} is before the recording starts")
    return t0 + x


def _column(names: Sequence[str], name: str | None, what: str) -> int:
    if name not in names:
        raise FaultError(f"unknown {what} {name!r}; the recording has {', '.join(names)}")
    return list(names).index(name)


def _encoder(rec: Recording, fault: Fault, start: float) -> Recording:
    j = _column(rec.joint_names, fault.get("joint"), "joint")
    if rec.q is None:
        raise FaultError("the recording has no encoder positions q")
    on = rec.encoder_t >= start
    if not on.any():
        raise FaultError(f"{fault.kind}: starts after the encoder stream ends")
    q = rec.q.copy()
    rates = {k: (None if getattr(rec, k) is None else getattr(rec, k).copy()) for k in ("qd", "qdd")}
    if fault.kind == "encoder_frozen":
        first = int(np.flatnonzero(on)[0])
        q[on, j] = q[max(first - 1, 0), j]
        for v in rates.values():
            if v is not None:
                v[on, j] = 0.0
    elif fault.kind == "encoder_offset":
        q[on, j] += np.radians(fault.number("deg"))
    else:  # encoder_sign
        q[on, j] = -q[on, j]
        for v in rates.values():
            if v is not None:
                v[on, j] = -v[on, j]
    return replace(rec, q=q, **rates)


def _imu(rec: Recording, fault: Fault, start: float) -> tuple[Recording, float | None]:
    k = _column(rec.imu_names, fault.get("imu"), "IMU")
    acc, gyro = rec.acc.copy(), rec.gyro.copy()
    if fault.kind == "imu_rotated":
        axis = np.array(_AXES[fault.get("axis", "x") or "x"])
        R = axis_rotations(axis, np.radians([fault.number("deg")]))[0]
        on = rec.t >= start
        acc[on, k] = acc[on, k] @ R.T
        gyro[on, k] = gyro[on, k] @ R.T
        return replace(rec, acc=acc, gyro=gyro), None
    seconds = fault.number("seconds")
    if seconds <= 0:
        raise FaultError(f"{fault.kind}: seconds must be > 0")
    on = (rec.t >= start) & (rec.t < start + seconds)
    if not on.any():
        raise FaultError(f"{fault.kind}: no IMU sample between {start:.3f} and {start + seconds:.3f} s")
    last = max(int(np.flatnonzero(on)[0]) - 1, 0)
    acc[on, k] = acc[last, k]
    gyro[on, k] = gyro[last, k]
    return replace(rec, acc=acc, gyro=gyro), start + seconds


def injected_faults(rec: Recording) -> list[dict[str, Any]]:
    """The faults injected into ``rec`` so far (empty for an untouched recording)."""
    raw = rec.extra.get("injected_faults")
    return [] if raw is None else list(json.loads(str(np.asarray(raw).reshape(()))))


def inject(rec: Recording, fault: Fault, seed: int = 0) -> Recording:
    """``rec`` with ``fault`` applied and recorded in ``extra["injected_faults"]``."""
    rng = np.random.default_rng(seed)
    start = _start(rec, fault, rng)
    stop: float | None = None
    if fault.kind.startswith("encoder_"):
        out = _encoder(rec, fault, start)
    else:
        out, stop = _imu(rec, fault, start)
    t0 = float(min(rec.t[0], rec.encoder_t[0]))
    entry = {
        "kind": fault.kind,
        "params": dict(fault.params),
        "start_s": round(start - t0, 9),
        "stop_s": None if stop is None else round(stop - t0, 9),
        "seed": seed,
    }
    extra = dict(out.extra)
    extra["injected_faults"] = np.asarray(json.dumps([*injected_faults(rec), entry]))
    return replace(out, extra=extra)


def inject_all(rec: Recording, faults: Sequence[Fault], seed: int = 0) -> Recording:
    """Apply ``faults`` in order (fault ``i`` draws from ``seed + i``)."""
    for i, f in enumerate(faults):
        rec = inject(rec, f, seed + i)
    return rec
