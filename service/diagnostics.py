"""A robot's health as ROS diagnostics: one ``diagnostic_msgs/DiagnosticStatus`` per robot and per part.

ROS tools (rqt_robot_monitor, the diagnostic aggregator, Foxglove) show ``/diagnostics`` topics, so the
monitoring answer is also given in that shape (``GET /api/v1/robots/{robot}/diagnostics``; docs/service.md
shows a bridge to a ROS 2 topic). It is built from what the store and :mod:`service.status` already know;
nothing here writes.

Entries are named ``bodyhealth/<robot>`` (the robot) and ``bodyhealth/<robot>/<part>`` with ``<part>``
the key alerts use (``imu:<name>``, ``joint:<name>``); ``hardware_id`` is the robot. Levels:

===========  ===============================================================================================
``ERROR`` 2  damage: the part has an active alert (confirmed over several worker cycles; an acknowledged
             alert is still active); the robot when its status is ``damaged``
``STALE`` 3  a silent sensor: an IMU not heard for ``imu_silent_seconds`` of device time before the robot's
             newest frame; the robot when it never sent a frame. Kept apart from ERROR: silence is
             missing data, not a finding (an IMU that is both silent and damaged reports ERROR, with
             ``silent`` true among its values)
``WARN`` 1   worth a look, not damage: a pending (unconfirmed) alert on the part, a joint the window did
             not move enough to place; the robot when its status is ``undetermined``
``OK`` 0     none of these
===========  ===============================================================================================

Example
-------
>>> from service.status import judge
>>> from service.store import RobotInfo
>>> from bodyschema.topology import Topology
>>> topo = Topology({"j1": None}, {"c1": "j1"})
>>> info = RobotInfo("arm", ["j1"], ["c1"], ["c1"], 0.0, 5.0, False, None)
>>> [(d.name, d.level) for d in diagnose(info, judge("arm", topo, topo))]
[('bodyhealth/arm', 0), ('bodyhealth/arm/joint:j1', 0), ('bodyhealth/arm/imu:c1', 3)]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from service.status import RobotStatus
from service.store import AlertRecord, RobotInfo

__all__ = ["ERROR", "LEVEL_NAMES", "OK", "STALE", "WARN", "DiagnosticStatus", "diagnose"]

OK: Final = 0
WARN: Final = 1
ERROR: Final = 2
STALE: Final = 3
#: diagnostic_msgs/DiagnosticStatus level constants, by value.
LEVEL_NAMES: dict[int, str] = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
_STATUS_LEVEL = {"healthy": OK, "undetermined": WARN, "damaged": ERROR}


@dataclass(frozen=True)
class DiagnosticStatus:
    """One ``diagnostic_msgs/DiagnosticStatus``: ``values`` are (key, value) strings, as in ROS."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...] = ()


def _alert_text(a: AlertRecord) -> str:
    detail = a.finding.get("detail") if a.finding else None
    return f"{a.kind}{f' ({detail})' if detail else ''}"


def _by_part(alerts: Sequence[AlertRecord]) -> dict[str, list[AlertRecord]]:
    out: dict[str, list[AlertRecord]] = {}
    for a in alerts:
        out.setdefault(a.part, []).append(a)
    return out


def _robot_entry(info: RobotInfo, st: RobotStatus) -> DiagnosticStatus:
    if info.last_frame_t is None:
        level, message = STALE, "no frame received yet"
    else:
        level, message = (
            _STATUS_LEVEL[st.status],
            f"{st.status}: {st.reasons[0]}" if st.reasons else st.status,
        )
    values: list[tuple[str, str]] = [
        ("status", st.status),
        ("trees_fit", "" if st.trees_fit is None else str(st.trees_fit)),
        ("active_alerts", str(len(st.alerts))),
        ("pending_alerts", str(len(st.pending))),
        ("silent_imus", ",".join(info.silent_imus)),
        ("last_frame_t", "" if info.last_frame_t is None else f"{info.last_frame_t:.6f}"),
        ("has_baseline", str(st.baseline is not None).lower()),
    ]
    values += [(k, f"{v:.3f}") for k, v in st.timing.items() if v is not None and k in ("skew_ms", "lag_ms")]
    return DiagnosticStatus(level, f"bodyhealth/{info.name}", message, info.name, tuple(values))


def _part_level(
    active: list[AlertRecord], pending: list[AlertRecord], silent: bool, unplaced: bool
) -> tuple[int, str]:
    if active:
        return ERROR, "; ".join(_alert_text(a) for a in active)
    if silent:
        return STALE, "silent: no data for the last seconds of the robot's device time"
    if pending:
        return WARN, "not yet confirmed: " + "; ".join(_alert_text(a) for a in pending)
    if unplaced:
        return WARN, "not moved enough in the window to be placed"
    return OK, "ok"


def diagnose(info: RobotInfo, st: RobotStatus) -> list[DiagnosticStatus]:
    """The robot's entry, then one per joint and per IMU (and per other part with an open alert), from
    what the store knows of the robot and its :func:`~service.status.judge` answer (pure)."""
    active, pending = _by_part(st.alerts), _by_part(st.pending)
    topo, base = st.topology, st.baseline.topology if st.baseline is not None else None
    out = [_robot_entry(info, st)]
    parts = [f"joint:{j}" for j in info.joints] + [f"imu:{i}" for i in info.imus]
    parts += sorted(p for p in {*active, *pending} if p not in parts)
    silent = set(info.silent_imus)
    for part in parts:
        kind, _, name = part.partition(":")
        values: list[tuple[str, str]] = []
        if topo is not None:
            where = topo.joint_parent if kind == "joint" else topo.imu_joint
            key = "parent" if kind == "joint" else "joint"
            if name in where:
                values.append((key, where[name] or "base"))
            conf = topo.confidence.get(part)
            if conf is not None:
                values.append(("confidence", f"{conf:.3f}"))
        if base is not None:
            where = base.joint_parent if kind == "joint" else base.imu_joint
            if name in where:
                values.append((f"baseline_{'parent' if kind == 'joint' else 'joint'}", where[name] or "base"))
        if kind == "joint" and name in info.excitation:
            values.append(("excitation_rad_s", f"{info.excitation[name]:.4f}"))
        if kind == "imu":
            values.append(("silent", str(name in silent).lower()))
        unplaced = kind == "joint" and name in st.insufficient_excitation
        is_silent = kind == "imu" and name in silent
        level, message = _part_level(active.get(part, []), pending.get(part, []), is_silent, unplaced)
        out.append(
            DiagnosticStatus(level, f"bodyhealth/{info.name}/{part}", message, info.name, tuple(values))
        )
    return out
