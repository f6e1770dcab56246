"""The import map: a TOML file saying which columns (CSV) or datasets (MATLAB) of a robot's log hold what.

The schema is documented in docs/recording-format.md ("Importing CSV and MAT logs"); two maps ship in
``examples/import/``. Parsing is strict: a key the schema does not know is refused with the keys it
does know that look closest, so a typo (``velocites``) does not silently drop a stream.

Example
-------
>>> m = parse_map({"clock": {"time": "t"}, "joints": {"positions": ["a", "b"]},
...                "imus": [{"name": "imu0", "acc": "acc*", "gyro": ["wx", "wy", "wz"]}]})
>>> m.positions.unit, m.positions.unit_stated, m.imus[0].acc.source
('rad', False, 'acc*')
"""

from __future__ import annotations

import difflib
import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bodyschema.recording import GRAVITY, RecordingError

__all__ = [
    "ACC_UNITS",
    "ANGLE_UNITS",
    "RATE_UNITS",
    "STANDARD_GRAVITY",
    "TIME_UNITS",
    "ExtraSpec",
    "ImuSpec",
    "LogMap",
    "MapError",
    "StreamSpec",
    "close_matches",
    "load_map",
    "parse_map",
]

#: The unit g, by definition (CGPM 1901), m/s²: what an accelerometer logged "in g" is scaled by.
STANDARD_GRAVITY = 9.80665
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180}
RATE_UNITS = {"rad/s": 1.0, "deg/s": math.pi / 180}
ACC_UNITS = {"m/s^2": 1.0, "m/s²": 1.0, "m/s2": 1.0, "g": STANDARD_GRAVITY}

#: A stream's source: a list of CSV columns, one glob pattern over CSV columns, or one MATLAB dataset.
Source = str | tuple[str, ...]


class MapError(RecordingError):
    """An import map that does not fit the schema (unknown key, wrong type, unknown unit)."""


def close_matches(word: str, choices: list[str] | tuple[str, ...], n: int = 5) -> str:
    """``"; close matches: a, b"`` (difflib, ignoring case), or ``""`` when nothing is close.

    The cutoff 0.4 keeps a name that shares its stem with the word (``imuOmega`` -> ``imuAcc``).
    """
    lower: dict[str, str] = {}
    for c in choices:
        lower.setdefault(c.lower(), c)
    near = [lower[c] for c in difflib.get_close_matches(word.lower(), list(lower), n=n, cutoff=0.4)]
    return f"; close matches: {', '.join(near)}" if near else ""


@dataclass(frozen=True)
class StreamSpec:
    """One stream of the log: where it is, its unit (and whether the map stated it), its clock."""

    source: Source
    unit: str
    unit_stated: bool
    time: str
    where: str  # the map key, for messages: "joints.positions", "imus[0].acc"


@dataclass(frozen=True)
class ImuSpec:
    """One IMU: its name in the recording and its accelerometer and gyro streams."""

    name: str
    acc: StreamSpec
    gyro: StreamSpec


@dataclass(frozen=True)
class ExtraSpec:
    """An array carried into ``Recording.extra`` untouched (samples first), e.g. foot forces."""

    name: str
    source: Source
    optional: bool
    unit: str | None
    where: str


@dataclass(frozen=True)
class LogMap:
    """A parsed import map (docs/recording-format.md, "Importing CSV and MAT logs")."""

    format: str | None
    time_unit: str
    time_unit_stated: bool
    positions: StreamSpec
    joint_names: tuple[str, ...] | None
    velocities: StreamSpec | None
    imus: tuple[ImuSpec, ...]
    extras: tuple[ExtraSpec, ...]
    gravity: np.ndarray
    gravity_stated: bool
    gap_factor: float


_TOP = ("format", "gravity", "gap_factor", "clock", "joints", "imus", "extras")
_CLOCK = ("time", "unit")
_JOINTS = ("positions", "names", "unit", "velocities", "velocity_unit", "time")
_IMU = ("name", "acc", "gyro", "acc_unit", "gyro_unit", "time")
_EXTRA = ("name", "source", "optional", "unit")


def _keys(table: Any, allowed: tuple[str, ...], where: str) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise MapError(f"{where} must be a table, got {type(table).__name__}")
    for k in table:
        if k not in allowed:
            raise MapError(
                f"unknown key {where}.{k}{close_matches(k, allowed)} (known: {', '.join(allowed)})"
            )
    return table


def _source(v: Any, where: str) -> Source:
    if isinstance(v, str) and v:
        return v
    if isinstance(v, list) and v and all(isinstance(x, str) and x for x in v):
        return tuple(v)
    raise MapError(f"{where} must be a column/dataset name, a glob, or a list of column names")


def _unit(
    table: dict[str, Any], key: str, units: dict[str, float], default: str, where: str
) -> tuple[str, bool]:
    if key not in table:
        return default, False
    u = table[key]
    if u not in units:
        raise MapError(f"{where}.{key} = {u!r}: unknown unit (known: {', '.join(units)})")
    return str(u), True


def _name(table: dict[str, Any], where: str) -> str:
    name = table.get("name")
    if not isinstance(name, str) or not name:
        raise MapError(f"{where}.name must be a non-empty string")
    return name


def _stream(
    table: dict[str, Any],
    key: str,
    units: dict[str, float],
    unit_key: str,
    default: str,
    clock: str,
    where: str,
) -> StreamSpec:
    if key not in table:
        raise MapError(f"{where}.{key} is missing")
    unit, stated = _unit(table, unit_key, units, default, where)
    time = table.get("time", clock)
    if not isinstance(time, str) or not time:
        raise MapError(f"{where}.time must be a column/dataset name")
    return StreamSpec(_source(table[key], f"{where}.{key}"), unit, stated, time, f"{where}.{key}")


def _joints(j: dict[str, Any], clock: str) -> tuple[StreamSpec, tuple[str, ...] | None, StreamSpec | None]:
    pos = _stream(j, "positions", ANGLE_UNITS, "unit", "rad", clock, "joints")
    names = j.get("names")
    if names is not None:
        if not (isinstance(names, list) and names and all(isinstance(x, str) and x for x in names)):
            raise MapError("joints.names must be a list of joint names")
        if len(set(names)) != len(names):
            dup = next(x for x in names if names.count(x) > 1)
            raise MapError(f"joints.names lists {dup!r} twice")
        names = tuple(names)
    vel = None
    if "velocities" in j:
        vel = _stream(j, "velocities", RATE_UNITS, "velocity_unit", "rad/s", clock, "joints")
        vel = StreamSpec(vel.source, vel.unit, vel.unit_stated, pos.time, vel.where)
    elif "velocity_unit" in j:
        raise MapError("joints.velocity_unit is given but joints.velocities is not")
    return pos, names, vel


def _imus(raw: Any, clock: str) -> tuple[ImuSpec, ...]:
    if not isinstance(raw, list) or not raw:
        raise MapError("imus must be a list of tables ([[imus]]), at least one")
    out = []
    for i, table in enumerate(raw):
        where = f"imus[{i}]"
        table = _keys(table, _IMU, where)
        name = _name(table, where)
        acc = _stream(table, "acc", ACC_UNITS, "acc_unit", "m/s^2", clock, where)
        gyro = _stream(table, "gyro", RATE_UNITS, "gyro_unit", "rad/s", clock, where)
        out.append(ImuSpec(name, acc, gyro))
    names = [m.name for m in out]
    if len(set(names)) != len(names):
        raise MapError(f"imus: names must be unique, got {names}")
    return tuple(out)


def _extras(raw: Any) -> tuple[ExtraSpec, ...]:
    if not isinstance(raw, list):
        raise MapError("extras must be a list of tables ([[extras]])")
    out = []
    for i, table in enumerate(raw):
        where = f"extras[{i}]"
        table = _keys(table, _EXTRA, where)
        name = _name(table, where)
        if "source" not in table:
            raise MapError(f"{where}.source is missing")
        optional = table.get("optional", False)
        if not isinstance(optional, bool):
            raise MapError(f"{where}.optional must be true or false")
        unit = table.get("unit")
        src = _source(table["source"], f"{where}.source")
        out.append(ExtraSpec(name, src, optional, None if unit is None else str(unit), where))
    names = [e.name for e in out]
    if len(set(names)) != len(names):
        raise MapError(f"extras: names must be unique, got {names}")
    return tuple(out)


def parse_map(raw: dict[str, Any]) -> LogMap:
    """A :class:`LogMap` from the map's TOML document (already parsed); :class:`MapError` if it breaks
    the schema. Units not given are assumed (rad, rad/s, m/s², rad/s, s) and reported as assumed."""
    raw = _keys(raw, _TOP, "map")
    fmt = raw.get("format")
    if fmt not in (None, "csv", "mat"):
        raise MapError(f"format = {fmt!r}: must be 'csv' or 'mat'")
    clock_t = _keys(raw.get("clock", {}), _CLOCK, "clock")
    clock = clock_t.get("time", "")
    time_unit, time_stated = _unit(clock_t, "unit", TIME_UNITS, "s", "clock")
    joints = _keys(raw.get("joints"), _JOINTS, "joints") if "joints" in raw else None
    if joints is None:
        raise MapError("the map has no [joints] table (joints.positions is required)")
    if not clock:
        tables = raw.get("imus") if isinstance(raw.get("imus"), list) else []
        if "time" not in joints or not tables or any("time" not in m for m in tables if isinstance(m, dict)):
            raise MapError("clock.time is missing (or give joints.time and every imus[].time)")
    pos, names, vel = _joints(joints, clock)
    imus = _imus(raw.get("imus"), clock)
    if len({m.acc.time for m in imus} | {m.gyro.time for m in imus}) > 1:
        raise MapError("every IMU must be on one clock (a recording has one IMU clock t)")
    gravity = raw.get("gravity")
    if gravity is not None:
        g = np.asarray(gravity, dtype=np.float64) if isinstance(gravity, list) else np.zeros(0)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise MapError(f"gravity must be three numbers (world frame, m/s²), got {gravity!r}")
    gap = raw.get("gap_factor", 1.5)
    if not isinstance(gap, int | float) or not gap > 1:
        raise MapError(f"gap_factor must be a number above 1, got {gap!r}")
    return LogMap(
        format=fmt,
        time_unit=time_unit,
        time_unit_stated=time_stated,
        positions=pos,
        joint_names=names,
        velocities=vel,
        imus=imus,
        extras=_extras(raw.get("extras", [])),
        gravity=GRAVITY.copy() if gravity is None else g,
        gravity_stated=gravity is not None,
        gap_factor=float(gap),
    )


def load_map(path: str | os.PathLike[str]) -> LogMap:
    """Read and parse an import map (TOML); the file name leads every error message."""
    try:
        raw = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as err:
        raise MapError(f"{path}: cannot read the import map ({err})") from err
    except tomllib.TOMLDecodeError as err:
        raise MapError(f"{path}: not valid TOML ({err})") from err
    try:
        return parse_map(raw)
    except MapError as err:
        raise MapError(f"{path}: {err}") from err
