"""Open an ingest source from a one-line spec (command line, settings, API).

=======================================================  ==========================================
``replay:PATH[@SPEED][?robot=NAME&loop=1&chunk=0.1]``     an ``.npz`` recording at SPEED × real time
``rosbag:PATH[@SPEED][?robot=NAME&imu_topics=/a,/b&...]``  a ROS bag, replayed like a recording
``farm:ur5e,paper-3,quadruped[@SPEED][?seed=0&...]``     the simulated farm (``ur5e*3`` = three UR5e)
``can:...``                                              :func:`service.ingest.can.open_from_spec`
``serial:...``                                           :func:`service.ingest.serial.open_from_spec`
=======================================================  ==========================================

SPEED is a positive number or ``max`` (as fast as possible); it defaults to 1. Farm options: ``seed``
(default: the settings' ``farm_seed``), ``rate`` (Hz, 100), ``imu_model`` (``mpu6050``), ``excitation``
(``observable``), ``step`` (simulated seconds per batch, 0.1), ``sensing`` (``robot`` or ``ideal``,
default: the settings' ``sensing``; ``rate`` is the physics rate only under ``ideal``), ``process``
(``1``, the default: the farm runs in a child process, :class:`~service.ingest.farm.FarmProcess`, as
robots are not in the service's process; ``0``: in the reader thread). Replay option
``resume=0`` replays from the start even when the store already has later frames. A ROS bag takes the
replay options plus ``imu_topics`` and ``joint_topics`` (comma-separated; default: every
``sensor_msgs/msg/Imu`` and ``sensor_msgs/msg/JointState`` topic); it is read into a recording
(:func:`service.ingest.rosbag.read_rosbag`: header stamps, each stream on its own) and replayed by the
same :class:`~service.ingest.replay.ReplaySource`; the robot is named after the bag unless ``robot``
says otherwise.

Example
-------
>>> parse_speed_suffix("data/run.npz@10")
('data/run.npz', 10.0)
>>> parse_speed_suffix("ur5e*2,paper-3@max")
('ur5e*2,paper-3', inf)
>>> farm_catalog("ur5e*2,paper-3")
['ur5e', 'ur5e', 'paper-3']
"""

from __future__ import annotations

import importlib
import math
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from bodyschema.recording import Recording
from service.ingest.base import Source
from service.settings import Settings, get_settings

__all__ = ["SpecError", "farm_catalog", "open_source", "parse_speed_suffix"]


class SpecError(ValueError):
    """A source spec that cannot be understood."""


def parse_speed_suffix(text: str) -> tuple[str, float]:
    """Split ``WHAT@SPEED`` into ``(WHAT, speed)``; no suffix means 1×, ``max``/``inf`` means unpaced."""
    what, sep, speed = text.rpartition("@")
    if not sep:
        return text, 1.0
    if speed.lower() in ("max", "inf"):
        return what, math.inf
    try:
        value = float(speed)
    except ValueError:
        return text, 1.0  # an '@' that is part of the name, not a speed
    if not value > 0 or math.isnan(value):
        raise SpecError(f"speed must be positive or 'max', got {speed!r}")
    return what, value


def farm_catalog(robots: str) -> list[str]:
    """Catalog names from ``ur5e,paper-3*2``: one entry per robot."""
    out: list[str] = []
    for item in filter(None, (s.strip() for s in robots.split(","))):
        name, star, count = item.partition("*")
        try:
            n = int(count) if star else 1
        except ValueError:
            raise SpecError(f"bad robot count in {item!r}") from None
        if n < 1 or not name:
            raise SpecError(f"bad farm robot {item!r}")
        out.extend([name] * n)
    if not out:
        raise SpecError("farm spec names no robot, e.g. farm:ur5e,paper-3")
    return out


def _params(query: str, allowed: set[str], kind: str) -> dict[str, str]:
    params = {k: v[-1] for k, v in parse_qs(query, keep_blank_values=True).items()}
    unknown = set(params) - allowed
    if unknown:
        raise SpecError(f"unknown {kind} option(s) {sorted(unknown)}; known: {sorted(allowed)}")
    return params


def _flag(v: str) -> bool:
    return v.lower() in ("1", "true", "yes", "on")


_REPLAY_OPTIONS = {"robot", "loop", "chunk", "resume"}


def _topics(v: str | None) -> tuple[str, ...]:
    return tuple(filter(None, (x.strip() for x in (v or "").split(","))))


def _open_replay(kind: str, rest: str) -> Source:
    """A recording (``replay``) or a ROS bag (``rosbag``) played by the one replay source."""
    from service.ingest.replay import ReplaySource

    body, _, query = rest.partition("?")
    topics = {"imu_topics", "joint_topics"} if kind == "rosbag" else set()
    p = _params(query, _REPLAY_OPTIONS | topics, kind)
    path, speed = parse_speed_suffix(body)
    recording: Recording | str = path
    robot = p.get("robot") or None
    if kind == "rosbag":
        from service.ingest.rosbag import RosbagOptions, part_name, read_rosbag

        opts = RosbagOptions(
            imu_topics=_topics(p.get("imu_topics")), joint_topics=_topics(p.get("joint_topics"))
        )
        recording, _ = read_rosbag(path, opts)
        robot = robot or part_name(Path(path).stem)
    return ReplaySource(
        recording,
        robot=robot,
        speed=speed,
        chunk_seconds=float(p.get("chunk", 0.1)),
        loop=_flag(p.get("loop", "0")),
        resume=_flag(p.get("resume", "1")),
        name=f"{kind}:{robot}" if kind == "rosbag" else None,
    )


def open_source(spec: str, settings: Settings | None = None) -> Source:
    """The source a spec names (see the module docstring); :class:`SpecError` when malformed."""
    settings = settings or get_settings()
    kind, sep, rest = spec.partition(":")
    if not sep or not rest:
        raise SpecError(
            f"source spec must look like KIND:ARGS (replay, rosbag, farm, can, serial), got {spec!r}"
        )
    kind = kind.strip().lower()
    if kind in ("replay", "rosbag"):
        return _open_replay(kind, rest)
    if kind == "farm":
        from service.ingest.farm import FarmSource, farm_robot_names

        body, _, query = rest.partition("?")
        p = _params(query, {"seed", "rate", "imu_model", "excitation", "step", "sensing", "process"}, "farm")
        robots, speed = parse_speed_suffix(body)
        in_child = p.get("process", "1")
        if in_child not in ("0", "1"):
            raise SpecError(f"farm option process must be 0 or 1, got {in_child!r}")
        kwargs = {
            "robots": farm_robot_names(farm_catalog(robots)),
            "seed": int(p.get("seed", settings.farm_seed)),
            "imu_model": p.get("imu_model", "mpu6050"),
            "excitation": p.get("excitation", "observable"),
            "rate": float(p.get("rate", 100.0)),
            "sensing": p.get("sensing", settings.sensing),
        }
        if in_child == "1":
            from service.ingest.farm import FarmProcess

            farm: Any = FarmProcess(**kwargs)
        else:
            from simulators.farm import Farm  # heavy (MuJoCo): only when a farm is asked for

            farm = Farm(**kwargs)
        return FarmSource(farm, speed=speed, step_seconds=float(p.get("step", 0.1)))
    if kind in ("can", "serial"):
        module = importlib.import_module(f"service.ingest.{kind}")
        return module.open_from_spec(rest)
    raise SpecError(f"unknown source kind {kind!r} in {spec!r}; expected replay, rosbag, farm, can or serial")
