"""Joint limits for excitation plans: from a robot model (URDF, MJCF, catalog name) or a TOML file.

* URDF: ``<limit lower upper velocity>`` of each revolute/prismatic joint (a ``continuous`` joint has
  no position limits); URDF has no acceleration limit.
* MJCF: a joint's ``range`` (when limited) and the ``ctrlrange`` of a velocity actuator on it
  (``<velocity joint=...>``: a gain on the velocity error, no position term).
* A limits file (TOML) overrides or supplies any of them::

      [defaults]            # for joints the model and the table leave open
      velocity = 1.0        # rad/s
      acceleration = 4.0    # rad/s²

      [joints.j1]
      lower = -1.5          # rad
      upper = 1.5
      velocity = 0.8
      acceleration = 3.0

A limit nobody states takes the default (:data:`DEFAULT_VELOCITY`, :data:`DEFAULT_ACCELERATION`: what a
small servo arm sustains; the simulators' servos track 1 rad/s at 1 Hz without saturating), and a
position range nobody states stays open (the planner then moves ``free_range`` about the start).

>>> lim = model_limits("paper-1")
>>> lim.names[:2], float(lim.velocity[0])
(('j1', 'j2'), 1.0)
"""

from __future__ import annotations

import math
import os
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np

from bodyschema.excitation_plan import JointLimits
from simulators.builder import load_spec, robot_joint_names

__all__ = [
    "DEFAULT_ACCELERATION",
    "DEFAULT_VELOCITY",
    "load_limits",
    "model_limits",
    "robot_limits",
]

#: rad/s and rad/s² for joints whose limits nobody states.
DEFAULT_VELOCITY = 1.0
DEFAULT_ACCELERATION = 4.0
_FIELDS = ("lower", "upper", "velocity", "acceleration")


def _compiled(model: str) -> mujoco.MjModel:
    from simulators.catalog import CATALOG, build

    if model in CATALOG:
        return build(model).compile()
    if not os.path.exists(model):
        raise ValueError(f"unknown model {model!r}: not in the catalog ({', '.join(CATALOG)}) nor a file")
    return load_spec(model).compile()


def _velocity_actuators(m: mujoco.MjModel) -> dict[int, float]:
    """Joint id -> the tighter bound of the ``ctrlrange`` of a velocity actuator driving it."""
    out: dict[int, float] = {}
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or not m.actuator_ctrllimited[a]:
            continue
        bias = m.actuator_biasprm[a]
        if not (bias[1] == 0 and bias[2] < 0 and m.actuator_gainprm[a, 0] > 0):
            continue  # not a velocity servo
        lo, hi = m.actuator_ctrlrange[a]
        bound = min(abs(lo), abs(hi))
        if bound > 0:
            j = int(m.actuator_trnid[a, 0])
            out[j] = min(out.get(j, math.inf), float(bound))
    return out


def _urdf_limits(path: str) -> dict[str, dict[str, float]]:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as err:
        raise ValueError(f"{path}: not a readable URDF ({err})") from err
    out: dict[str, dict[str, float]] = {}
    for joint in root.iter("joint"):
        name, kind, lim = joint.get("name"), joint.get("type"), joint.find("limit")
        if not name or lim is None:
            continue
        entry: dict[str, float] = {}
        if kind in ("revolute", "prismatic"):
            for f in ("lower", "upper"):
                if lim.get(f) is not None:
                    entry[f] = float(lim.get(f))  # type: ignore[arg-type]
        if lim.get("velocity") is not None and float(lim.get("velocity")) > 0:  # type: ignore[arg-type]
            entry["velocity"] = float(lim.get("velocity"))  # type: ignore[arg-type]
        out[name] = entry
    return out


def _stated(model: str) -> tuple[list[str], list[dict[str, float]]]:
    """Joint names in the simulators' order and, per joint, only the limits the model states."""
    m = _compiled(model)
    names = robot_joint_names(m)
    vel = _velocity_actuators(m)
    urdf = _urdf_limits(model) if model.lower().endswith(".urdf") and os.path.exists(model) else {}
    rows = []
    for n in names:
        j = m.joint(n).id
        row: dict[str, float] = {}
        if m.jnt_limited[j]:
            row["lower"], row["upper"] = (float(x) for x in m.jnt_range[j])
        if j in vel:
            row["velocity"] = vel[j]
        row.update(urdf.get(n, {}))
        rows.append(row)
    return names, rows


def _limits(names: list[str], rows: list[Mapping[str, float]], defaults: Mapping[str, Any]) -> JointLimits:
    """Rows completed with ``defaults`` (then the built-in ones, open ranges) as :class:`JointLimits`."""
    base = {
        "lower": -math.inf,
        "upper": math.inf,
        "velocity": float(defaults.get("velocity", DEFAULT_VELOCITY)),
        "acceleration": float(defaults.get("acceleration", DEFAULT_ACCELERATION)),
    }
    full = [{**base, **r} for r in rows]
    cols = {f: np.array([r[f] for r in full], dtype=np.float64) for f in _FIELDS}
    return JointLimits(tuple(names), cols["lower"], cols["upper"], cols["velocity"], cols["acceleration"])


def model_limits(model: str) -> JointLimits:
    """The limits a model states (URDF ``<limit>``; MJCF ``range`` and velocity ``ctrlrange``; a catalog
    robot's ranges), the built-in defaults where it states none; joints in the simulators' order."""
    names, rows = _stated(model)
    return _limits(names, rows, {})


def _read_toml(path: str) -> tuple[dict[str, Any], dict[str, Any]]:
    try:
        with open(path, "rb") as fh:
            doc: dict[str, Any] = tomllib.load(fh)
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{path}: not valid TOML ({err})") from err
    defaults, table = doc.get("defaults", {}), doc.get("joints", {})
    if not isinstance(table, dict) or not isinstance(defaults, dict):
        raise ValueError(f"{path}: [joints] and [defaults] must be tables")
    for n, entry in table.items():
        bad = sorted(set(entry) - set(_FIELDS)) if isinstance(entry, dict) else ["(not a table)"]
        if bad:
            raise ValueError(
                f"{path}: joint {n}: unknown key(s) {', '.join(bad)}; expected {', '.join(_FIELDS)}"
            )
    bad_defaults = sorted(set(defaults) - {"velocity", "acceleration"})
    if bad_defaults:
        raise ValueError(f"{path}: [defaults] takes velocity and acceleration, not {', '.join(bad_defaults)}")
    return defaults, table


def load_limits(model: str | None, limits_file: str | None) -> JointLimits:
    """The limits for ``bodyhealth excite``: what the model states, the file's joint entries laid over
    them, the file's ``[defaults]`` for what neither states (module docstring). Either source may be
    missing, not both; without a model the file's joints are the joints."""
    if model is None and limits_file is None:
        raise ValueError("give a model or a limits file")
    names, rows = _stated(model) if model is not None else ([], [])
    defaults: dict[str, Any] = {}
    if limits_file is not None:
        defaults, table = _read_toml(limits_file)
        if model is None:
            names, rows = list(table), [{} for _ in table]
        unknown = sorted(set(table) - set(names))
        if unknown:
            raise ValueError(f"{limits_file}: limits for unknown joint(s) {', '.join(unknown)}")
        rows = [
            {**r, **{k: float(v) for k, v in table.get(n, {}).items()}}
            for n, r in zip(names, rows, strict=True)
        ]
    return _limits(names, rows, defaults)


def robot_limits(robot: Any) -> JointLimits:
    """A compiled :class:`simulators.robot.Robot`'s ranges with the default rate limits."""
    m = robot.model
    rows = []
    vel = _velocity_actuators(m)
    for n in robot.joint_names:
        j = m.joint(n).id
        lo, hi = m.jnt_range[j] if m.jnt_limited[j] else (-math.inf, math.inf)
        rows.append(
            {
                "lower": float(lo),
                "upper": float(hi),
                "velocity": vel.get(j, DEFAULT_VELOCITY),
                "acceleration": DEFAULT_ACCELERATION,
            }
        )
    return _limits(list(robot.joint_names), rows, {})
