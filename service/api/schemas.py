"""Response and request bodies of the REST API (they make the OpenAPI document at ``/docs``).

Topologies and findings are passed through as the docs/design.md §2 JSON (plain dicts): that format is the
contract, and a second model of it here would drift.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from bodyschema.findings import DAMAGE_KINDS
from service.store import AlertRecord, RobotInfo, TopologyRecord

__all__ = ["AlertOut", "DamageIn", "DamageOut", "FramesIn", "RobotOut", "TopologyOut", "TopologyPair"]

DamageKind = Literal[DAMAGE_KINDS]  # type: ignore[valid-type]


class RobotOut(BaseModel):
    name: str
    joints: list[str]
    imus: list[str]
    silent_imus: list[str]
    simulated: bool
    catalog: str | None
    first_seen: float
    last_frame_t: float | None = Field(description="device time of the newest frame, s")
    excitation: dict[str, float] = Field(description="RMS joint velocity in the last window, rad/s")
    has_baseline: bool = False
    active_alerts: int = 0

    @classmethod
    def of(cls, r: RobotInfo, has_baseline: bool = False, active_alerts: int = 0) -> RobotOut:
        return cls(
            name=r.name,
            joints=r.joints,
            imus=r.imus,
            silent_imus=r.silent_imus,
            simulated=r.simulated,
            catalog=r.catalog,
            first_seen=r.first_seen,
            last_frame_t=r.last_frame_t,
            excitation=r.excitation,
            has_baseline=has_baseline,
            active_alerts=active_alerts,
        )


class TopologyOut(BaseModel):
    id: int
    wall_time: float
    window_end_t: float | None
    method: str
    source: str | None = None
    topology: dict[str, Any] = Field(description="docs/design.md §2 topology JSON")

    @classmethod
    def of(cls, r: TopologyRecord) -> TopologyOut:
        return cls(
            id=r.id,
            wall_time=r.wall_time,
            window_end_t=r.window_end_t,
            method=r.method,
            source=r.source,
            topology=r.topology.to_json(),
        )


class TopologyPair(BaseModel):
    current: dict[str, Any] | None = Field(description="newest learned topology (docs/design.md §2 JSON)")
    baseline: dict[str, Any] | None = Field(description="the baseline it is compared with")
    current_meta: TopologyOut | None = None
    baseline_meta: TopologyOut | None = None
    diff: dict[str, Any] | None = Field(
        None,
        description="docs/design.md §2 diff JSON of current vs baseline "
        "(structure only; alerts also use signal health)",
    )


class AlertOut(BaseModel):
    id: int
    robot: str
    kind: str
    part: str
    imu: str | None
    joint: str | None
    state: Literal["pending", "active", "resolved"]
    acked: bool
    raised_at: float
    resolved_at: float | None
    updated_at: float
    finding: dict[str, Any]

    @classmethod
    def of(cls, a: AlertRecord) -> AlertOut:
        return cls(
            id=a.id,
            robot=a.robot,
            kind=a.kind,
            part=a.part,
            imu=a.imu,
            joint=a.joint,
            state=a.state,
            acked=a.acked,
            raised_at=a.raised_at,
            resolved_at=a.resolved_at,
            updated_at=a.updated_at,
            finding=a.finding,
        )


class DamageIn(BaseModel):
    """A damage to inject into a simulated robot. Part arguments are optional: the simulator picks
    a part when they are left out."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: DamageKind = Field(description=f"one of {', '.join(DAMAGE_KINDS)}")
    imu: str | None = Field(None, max_length=200)
    joint: str | None = Field(None, max_length=200)
    to: str | None = Field(None, max_length=200, description="imu_moved: the joint the IMU moves to")
    value: float | None = Field(None, description="encoder_fault offset, rad (with mode 'offset')")
    mode: Literal["frozen", "zero", "stuck", "offset"] | None = Field(
        None, description="imu_dead: frozen|zero; encoder_fault: stuck|offset"
    )
    tether: float | None = Field(None, gt=0, le=1.0, description="imu_detached: tether length, m")


class DamageOut(BaseModel):
    robot: str
    kind: str
    truth: dict[str, Any] = Field(description="docs/design.md §2 diff JSON of what was injected")


class FramesIn(BaseModel):
    """Frames pushed over HTTP: the FrameBatch fields as nested lists (T samples)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    t: list[float] = Field(min_length=1)
    joint_names: list[str]
    q: list[list[float]]
    imu_names: list[str]
    acc: list[list[list[float]]]
    gyro: list[list[list[float]]]
