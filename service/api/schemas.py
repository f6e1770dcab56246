"""Response and request bodies of the REST API (they make the OpenAPI document at ``/docs``).

Topologies and findings are passed through as the JSON of docs/design.md, 'Exchange formats' (plain
dicts): that format is the contract, and a second model of it here would drift.
"""

from __future__ import annotations

import math
import time
from typing import Annotated, Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

from bodyschema.findings import DAMAGE_KINDS, KINEMATIC_KINDS
from bodyschema.lever_pool import POOL_KEY
from bodyschema.topology import Topology
from service.diagnostics import DiagnosticStatus
from service.frames import ACC_LIMIT, CHANNEL_LIMIT, GYRO_LIMIT, NAME_PATTERN, NAME_RULE, Q_LIMIT, T_LIMIT
from service.status import MAX_ALTERNATIVES, MethodsVerdict, RobotStatus
from service.store import AlertRecord, RobotInfo, StoredFloating, StoredKinematics, TopologyRecord

__all__ = [
    "DAMAGE_MODES",
    "DAMAGE_PARAMS",
    "AlertOut",
    "DamageIn",
    "DamageOut",
    "DiagnosticArrayOut",
    "DiagnosticStatusOut",
    "FramesIn",
    "KeyValueOut",
    "KinematicsOut",
    "KinematicsPair",
    "MethodsOut",
    "PartOut",
    "RetrainOut",
    "RobotOut",
    "StatusOut",
    "TimingOut",
    "TopologyOut",
    "TopologyPair",
    "TrainingOut",
]

#: What a simulated robot can be broken with: the topology's damages and the geometry drifts.
DamageKind = Literal[(*DAMAGE_KINDS, *KINEMATIC_KINDS)]  # type: ignore[valid-type]
#: A robot, joint or IMU name in a request body (the pattern every ingest source is held to).
PartName = Annotated[str, Field(pattern=NAME_PATTERN, description=NAME_RULE)]

#: One IMU axis triple (x, y, z) in a frames body.
Vector3 = Annotated[list[float], Field(min_length=3, max_length=3)]
#: A device time stamp, s (service.frames.T_LIMIT; the REST API also refuses negative stamps).
Stamp = Annotated[float, Field(ge=0, le=T_LIMIT)]
#: A joint position, rad or m (service.frames.Q_LIMIT).
Position = Annotated[float, Field(ge=-Q_LIMIT, le=Q_LIMIT)]
#: A value of an extra channel (a foot force), in the channel's own unit (service.frames.CHANNEL_LIMIT).
ChannelValue = Annotated[float, Field(ge=-CHANNEL_LIMIT, le=CHANNEL_LIMIT)]
#: One accelerometer triple, m/s² (service.frames.ACC_LIMIT per axis).
Acc3 = Annotated[
    list[Annotated[float, Field(ge=-ACC_LIMIT, le=ACC_LIMIT)]], Field(min_length=3, max_length=3)
]
#: One gyro triple, rad/s (service.frames.GYRO_LIMIT per axis).
Gyro3 = Annotated[
    list[Annotated[float, Field(ge=-GYRO_LIMIT, le=GYRO_LIMIT)]], Field(min_length=3, max_length=3)
]

#: The parameters each damage kind takes, as the farm's simulator applies them (simulators/damage.py);
#: a parameter another kind takes is refused here, with the kind's own list, before the farm sees it.
#: A kind not listed is passed through and answered by the farm.
DAMAGE_PARAMS: dict[str, tuple[str, ...]] = {
    "imu_moved": ("imu", "to"),
    "imu_detached": ("imu", "tether"),
    "imu_dead": ("imu", "mode"),
    "joint_locked": ("joint",),
    "encoder_fault": ("joint", "mode", "value"),
    "link_lost": ("joint",),
    "imu_rotated": ("imu", "angle_deg", "about"),
    "imu_shifted": ("imu", "meters"),
    "axis_changed": ("joint", "angle_deg"),
    "backlash": ("joint", "deg"),
}
#: The ``mode`` values of the kinds that take one.
DAMAGE_MODES: dict[str, tuple[str, ...]] = {
    "imu_dead": ("frozen", "zero"),
    "encoder_fault": ("stuck", "offset"),
}


M = TypeVar("M", bound=BaseModel)


def _copied(cls: type[M], record: object, **given: Any) -> M:
    """``cls`` with each of its fields read from the attribute of ``record`` of the same name, unless
    ``given``: the stores' records and the API's models name their fields alike."""
    fields = {f: getattr(record, f) for f in cls.model_fields if f not in given}
    return cls(**fields, **given)


class TopologyOut(BaseModel):
    id: int
    wall_time: float
    window_end_t: float | None
    method: str
    source: str | None = None
    cpu_seconds: float | None = Field(None, description="CPU seconds the estimate took")
    training: TrainingOut | None = Field(None, description="network methods: how training went")
    topology: dict[str, Any] = Field(description="topology JSON (docs/design.md, 'Topology JSON')")

    @classmethod
    def of(cls, r: TopologyRecord) -> TopologyOut:
        return cls(
            id=r.id,
            wall_time=r.wall_time,
            window_end_t=r.window_end_t,
            method=r.method,
            source=r.source,
            cpu_seconds=float(r.topology.seconds),
            training=TrainingOut.of(dict(r.topology.training)),
            topology=r.topology.to_json(),
        )


class TopologyPair(BaseModel):
    current: dict[str, Any] | None = Field(
        description="newest learned topology (docs/design.md, 'Topology JSON')"
    )
    baseline: dict[str, Any] | None = Field(description="the baseline it is compared with")
    current_meta: TopologyOut | None = None
    baseline_meta: TopologyOut | None = None
    diff: dict[str, Any] | None = Field(
        None,
        description="diff JSON (docs/design.md, 'Diff JSON') of current vs baseline "
        "(structure only; alerts also use signal health)",
    )


class KinematicsOut(BaseModel):
    """One kept geometry estimate of a robot."""

    id: int
    baseline_id: int = Field(description="the topology baseline it was estimated under")
    wall_time: float
    window_end_t: float | None = Field(description="device time at the end of the window it came from, s")
    kinematics: dict[str, Any] = Field(description="docs/kinematics.md JSON: joint axes, IMU lever arms")
    pooled_estimates: int = Field(
        0,
        description="geometry estimates whose lever arms are pooled with it to judge slides: under the "
        "baseline, those compared with (full at kinematics_pool_base); the newest, the recent ones "
        "(full at kinematics_pool_recent)",
    )

    @classmethod
    def of(cls, k: StoredKinematics | None) -> KinematicsOut | None:
        if k is None:
            return None
        data = {key: v for key, v in k.data.items() if key != POOL_KEY}
        return _copied(cls, k, kinematics=data, pooled_estimates=len(k.data.get(POOL_KEY) or ()))


class KinematicsPair(BaseModel):
    """A robot's geometry under its current topology baseline: as first learned and as now."""

    baseline: KinematicsOut | None = Field(
        description="the first geometry learned under the current topology baseline (drift compares with it)"
    )
    latest: KinematicsOut | None = Field(description="the newest geometry estimate under that baseline")
    drift: list[dict[str, Any]] | None = Field(
        None,
        description="findings (docs/design.md, 'Diff JSON') from baseline to latest (imu_rotated, "
        "imu_shifted, axis_changed, backlash), each beyond the two estimates' own uncertainty; alerts add "
        "hysteresis",
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
    confirmed: bool | None = Field(
        None,
        description="true: the sensor networks confirmed it; false: they did not answer in time and "
        "the fast screen's finding stands; null: not theirs to judge, or not judged yet",
    )
    note: str = Field("", description="why the alert is in its state (waiting, unconfirmed, withdrawn)")

    @classmethod
    def of(cls, a: AlertRecord) -> AlertOut:
        return _copied(cls, a)


class TimingOut(BaseModel):
    """How the IMU clock relates to the encoder clock, estimated from multi-rate data."""

    lag_ms: float | None = Field(
        None, description="IMU lag behind the encoders: clock skew plus filter delay"
    )
    lag_unc_ms: float | None = Field(
        None, description="the lag's uncertainty, ms (from 30 s of data on, like the drift)"
    )
    skew_ms: float | None = Field(None, description="IMU-to-encoder clock skew, ms")
    drift_ppm: float | None = Field(None, description="clock drift between the two, ppm")
    band_hz: float | None = Field(None, description="band the gyro and encoder rates were compared in, Hz")
    at_s: float | None = Field(None, description="encoder-clock time the lag holds at, s")

    @classmethod
    def of(cls, timing: dict[str, float | None]) -> TimingOut | None:
        """None when the estimate carries no timing (encoders and IMUs on one clock)."""
        return cls(**{k: v for k, v in timing.items() if k in cls.model_fields}) if timing else None


class TrainingOut(BaseModel):
    """How the sensor networks (or the MLP baseline) trained for this estimate."""

    epochs: int | None = None
    converged: bool | None = Field(
        None, description="training stopped on a flat loss rather than at its epoch bound"
    )
    loss: float | None = Field(None, description="last epoch's loss (null when it was not finite)")
    warm: bool | None = Field(
        None,
        description="sensor networks: training began from the robot's stored weights (true) or from "
        "random ones (false)",
    )

    @classmethod
    def of(cls, training: dict[str, float | None]) -> TrainingOut | None:
        """None for estimators that do not train (the fast one); the stored floats typed back."""
        if not training:
            return None
        epochs, converged, warm = training.get("epochs"), training.get("converged"), training.get("warm")
        loss = training.get("loss")
        return cls(
            epochs=None if epochs is None else int(epochs),
            converged=None if converged is None else bool(converged),
            loss=None if loss is None or not math.isfinite(loss) else float(loss),
            warm=None if warm is None else bool(warm),
        )


class RetrainOut(BaseModel):
    """The newest sensor-network topology of a robot: when, what it cost, how it trained, and whether
    it learned the same body as the estimate judged."""

    topology_id: int
    method: str
    wall_time: float = Field(description="when it was stored (wall clock, s)")
    window_end_t: float | None = Field(None, description="device time its window ended, s")
    cpu_seconds: float = Field(description="CPU seconds the retrain took where it ran")
    training: TrainingOut | None = None
    same_as_judged: bool | None = Field(
        None, description="it learned the same structure as the estimate judged (null: nothing judged)"
    )

    @classmethod
    def of(cls, r: TopologyRecord, judged: Topology | None) -> RetrainOut:
        return cls(
            topology_id=r.id,
            method=r.method,
            wall_time=r.wall_time,
            window_end_t=r.window_end_t,
            cpu_seconds=float(r.topology.seconds),
            training=TrainingOut.of(dict(r.topology.training)),
            same_as_judged=None if judged is None else r.topology.same_structure(judged),
        )


class PartOut(BaseModel):
    """One part of the body schema as the fast method and the sensor networks judge it together."""

    part: str = Field(
        description="joint:<name> (the joint it hangs under) or imu:<name> (the joint whose link carries it)"
    )
    verdict: Literal["agreed", "unconfirmed", "undetermined"] = Field(
        description="agreed: both methods decided it alike; unconfirmed: the networks have not answered "
        "and the fast method alone decided it; undetermined: a method left it open or the two contradict "
        "each other"
    )
    fast: str | None = Field(
        description="the fast method's answer: a joint name, null for the base (base link)"
    )
    network: str | None = Field(
        description="the sensor networks' answer, null for the base (base link) or when they have not "
        "answered (see methods.basis)"
    )
    fast_decided: bool = Field(description="the fast method decided this part (its candidate trees agree)")
    network_decided: bool = Field(
        description="the sensor networks decided this part (candidates agree, held-out confidence above 0.5)"
    )
    contradicted: bool = Field(
        description="both methods decided this part with different answers: the robot is not healthy on it"
    )
    confidence: float = Field(
        description="agreed: the larger of the two methods' confidences; otherwise at most 0.5"
    )
    move: list[str] = Field(
        default_factory=list,
        description="joints whose motion, each on its own with the others still, would decide this part "
        "(empty when agreed)",
    )


class MethodsOut(BaseModel):
    """What the two methods (fast, sensor networks) add up to over every part: what they were compared
    on, and how many parts have each verdict."""

    basis: Literal["fast+network", "fast", ""] = Field(
        description="fast+network: both answered and are compared; fast: the verdict rests on the fast "
        "method alone and is unconfirmed (note says why); empty: the fast method has learned nothing"
    )
    note: str = Field(description="the verdict in a sentence; why the networks' answer is not used")
    fast_topology_id: int | None = Field(None, description="the fast topology compared")
    network_topology_id: int | None = Field(
        None, description="the sensor networks' newest topology (compared unless basis is fast)"
    )
    network_window_end_t: float | None = Field(None, description="device time the networks' window ended, s")
    network_stale: bool = Field(
        False,
        description="the networks' newest topology is older than the baseline and shows another body, "
        "so it is not used",
    )
    agreed: int = Field(0, description="parts both methods decided alike")
    unconfirmed: int = Field(0, description="parts only the fast method answered and decided")
    undetermined: int = Field(0, description="parts left open by a method, or contradicted")
    contradicted: int = Field(
        0, description="of the undetermined: parts both methods decided with different answers"
    )

    @classmethod
    def of(cls, m: MethodsVerdict) -> MethodsOut:
        c = m.counts
        return cls(
            basis=m.basis,
            note=m.note,
            fast_topology_id=m.fast_id,
            network_topology_id=m.network_id,
            network_window_end_t=m.network_window_end_t,
            network_stale=m.network_stale,
            **c,
        )


def _parts(m: MethodsVerdict) -> list[PartOut]:
    return [
        PartOut(
            part=p.part,
            verdict=m.verdict(p),
            fast=p.fast,
            network=p.network,
            fast_decided=p.fast_decided,
            network_decided=p.network_decided,
            contradicted=p.contradicted,
            confidence=round(float(p.confidence), 6),
            move=list(p.move),
        )
        for p in m.parts
    ]


class StatusOut(BaseModel):
    """The monitoring answer for one robot: ``healthy``, ``damaged`` or ``undetermined``, and why.

    ``healthy`` only when one tree fits the newest estimate, every joint was placed, it matches a
    unique baseline, and nothing is pending or active; ``damaged`` when alerts are active (confirmed
    over several worker cycles); ``undetermined`` otherwise, with ``reasons``.
    """

    robot: str
    status: Literal["healthy", "damaged", "undetermined"]
    reasons: list[str] = Field(description="why this answer: trees that fit, missing baseline, alerts, ...")
    trees_fit: int | None = Field(
        description="trees that fit the newest estimate: 1 = unique; null = nothing learned, or not "
        "unique without the trees being listed"
    )
    alternatives: list[dict[str, Any]] = Field(
        default_factory=list,
        description=f"the other fitting trees ({{joints, imus}} as in the topology JSON), at most "
        f"{MAX_ALTERNATIVES}",
    )
    decide_by: list[str] = Field(
        default_factory=list,
        description="joints to move, each on its own with the others still, to decide between the trees "
        "or to place joints the data could not",
    )
    insufficient_excitation: list[str] = Field(
        default_factory=list, description="joints the newest window did not move enough to place"
    )
    alerts: list[AlertOut] = Field(default_factory=list, description="active alerts")
    pending_alerts: list[AlertOut] = Field(default_factory=list, description="seen, not yet confirmed")
    has_baseline: bool
    diff: dict[str, Any] | None = Field(
        None,
        description="diff JSON (docs/design.md, 'Diff JSON') of the newest estimate vs the baseline "
        "(structure only)",
    )
    topology_id: int | None = None
    method: str | None = Field(None, description="estimator of the topology judged")
    wall_time: float | None = Field(None, description="when it was learned (wall clock, s)")
    timing: TimingOut | None = Field(None, description="multi-rate robots: IMU-to-encoder timing")
    training: TrainingOut | None = Field(None, description="network methods: how training went")
    network: RetrainOut | None = Field(
        None, description="the newest sensor-network retrain (the schedule's, or one asked for)"
    )
    waiting: list[dict[str, Any]] = Field(
        default_factory=list,
        description="what the worker waits on for this robot: {what, since, until} (wall times, s)",
    )
    training_queue: list[dict[str, Any]] = Field(
        default_factory=list,
        description="this robot's retrains in the training queue: {method, state, position, since, "
        "expected_seconds, expected_finish, cpu_seconds, window_end}",
    )
    baseline_source: str | None = Field(None, description="auto, operator or fast-unconfirmed")
    baseline_kind: Literal["topology", "floating"] | None = Field(
        None,
        description="what the baseline is: a topology, or what the floating-base checks learned "
        "(a walking robot whose one IMU rides its base); null without one",
    )
    baseline_networks: str = Field(
        "", description="of a fast-unconfirmed baseline: agree, contradicted or unconfirmed"
    )
    parts: list[PartOut] = Field(
        default_factory=list,
        description="every joint and IMU as the newest fast topology and the newest sensor-network "
        "topology judge it together: the verdict, both answers, the confidence, the joints to move",
    )
    methods: MethodsOut = Field(
        default_factory=lambda: MethodsOut(basis="", note=""),
        description="what the parts' verdicts rest on (both methods, or the fast one alone) and how "
        "many parts have each verdict",
    )

    @classmethod
    def of(cls, st: RobotStatus, floating: StoredFloating | None = None) -> StatusOut:
        """The answer of ``st``; ``floating`` is the robot's floating baseline, when it has one and
        no topology baseline (a floating-base robot is judged against it, not against a topology)."""
        cur = st.current
        floating = floating if st.baseline is None else None
        return cls(
            robot=st.robot,
            status=st.status,
            reasons=_floating_reasons(st.reasons, floating),
            trees_fit=st.trees_fit,
            alternatives=[
                {"joints": {j: {"parent": p} for j, p in t.joint_parent.items()}, "imus": dict(t.imu_joint)}
                for t in st.alternatives
            ],
            decide_by=list(st.decide_by),
            insufficient_excitation=list(st.insufficient_excitation),
            alerts=[AlertOut.of(a) for a in st.alerts],
            pending_alerts=[AlertOut.of(a) for a in st.pending],
            has_baseline=st.baseline is not None or floating is not None,
            diff=st.diff.to_json() if st.diff is not None else None,
            topology_id=cur.id if cur else None,
            method=cur.method if cur else None,
            wall_time=cur.wall_time if cur else None,
            timing=TimingOut.of(st.timing),
            training=TrainingOut.of(st.training),
            network=RetrainOut.of(st.network, st.topology) if st.network is not None else None,
            waiting=list(st.waiting),
            training_queue=list(st.queue),
            baseline_source=st.baseline.source if st.baseline is not None else ("auto" if floating else None),
            baseline_kind="topology" if st.baseline is not None else ("floating" if floating else None),
            baseline_networks=st.baseline_networks,
            parts=_parts(st.methods),
            methods=MethodsOut.of(st.methods),
        )


#: The reasons :func:`service.status.judge` gives for a robot with no topology learned or no topology
#: baseline: a floating-base robot has neither by design, and its floating baseline says instead.
_TOPOLOGY_ONLY = ("nothing learned yet", "no baseline yet")


def _floating_reasons(reasons: tuple[str, ...], floating: StoredFloating | None) -> list[str]:
    """``reasons``, with those about a missing topology baseline put as what the floating baseline is."""
    if floating is None:
        return list(reasons)
    kept = [r for r in reasons if not r.startswith(_TOPOLOGY_ONLY)]
    learned = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(floating.wall_time))
    return [
        f"floating-base baseline learned {learned} ({floating.rule}): windows are judged by the "
        "floating-base checks, no topology is learned",
        *kept,
    ]


class RobotOut(BaseModel):
    name: str
    joints: list[str]
    imus: list[str]
    silent_imus: list[str]
    simulated: bool
    catalog: str | None
    first_seen: float
    last_frame_t: float | None = Field(description="device time of the newest frame, s")
    epoch: int = Field(0, description="times the robot's device clock went back (restarts seen)")
    epoch_start_t: float | None = Field(
        None, description="device time the current clock epoch began, s (null while it is the first)"
    )
    excitation: dict[str, float] = Field(description="RMS joint velocity in the last window, rad/s")
    has_baseline: bool = False
    active_alerts: int = 0
    status: StatusOut | None = Field(
        None, description="the monitoring answer, as GET /api/v1/robots/{robot}/status gives it"
    )

    @classmethod
    def of(
        cls,
        r: RobotInfo,
        has_baseline: bool = False,
        active_alerts: int = 0,
        status: StatusOut | None = None,
    ) -> RobotOut:
        return cls(
            name=r.name,
            joints=r.joints,
            imus=r.imus,
            silent_imus=r.silent_imus,
            simulated=r.simulated,
            catalog=r.catalog,
            first_seen=r.first_seen,
            last_frame_t=r.last_frame_t,
            epoch=r.epoch,
            epoch_start_t=r.epoch_start_t,
            excitation=r.excitation,
            has_baseline=has_baseline,
            active_alerts=active_alerts,
            status=status,
        )


def _damage_variants(schema: dict[str, Any]) -> None:
    """The body's JSON Schema says per kind what :meth:`DamageIn._params_fit_kind` accepts: one
    ``oneOf`` branch per kind, in which a parameter the kind does not take may only be null and
    ``mode`` is one of the kind's own modes."""
    names = _damage_args()
    variants: list[dict[str, Any]] = []
    for kind in (*DAMAGE_KINDS, *KINEMATIC_KINDS):
        props: dict[str, Any] = {"kind": {"const": kind}}
        allowed = DAMAGE_PARAMS.get(kind)
        if allowed is not None:
            props.update({k: {"type": "null"} for k in names if k not in allowed})
            if "mode" in allowed:
                props["mode"] = {"anyOf": [{"enum": list(DAMAGE_MODES[kind])}, {"type": "null"}]}
        variants.append({"properties": props, "required": ["kind"]})
    schema["oneOf"] = variants
    schema["examples"] = [{"kind": "imu_dead", "imu": "imu0", "mode": "frozen"}]


def _damage_args() -> tuple[str, ...]:
    """Every optional part of a damage body, in the order the schema lists them: the fields of
    :class:`DamageIn` but its ``kind``."""
    return tuple(k for k in DamageIn.model_fields if k != "kind")


class DamageIn(BaseModel):
    """A damage to apply to a simulated robot. Part arguments are optional: the simulator picks
    a part when they are left out."""

    # strict: a number field takes numbers only (true is not 1.0, "1" is not 1.0)
    model_config = ConfigDict(
        extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra=_damage_variants
    )

    kind: DamageKind = Field(description=f"one of {', '.join((*DAMAGE_KINDS, *KINEMATIC_KINDS))}")
    imu: PartName | None = None
    joint: PartName | None = None
    to: PartName | None = Field(None, description="imu_moved: the joint the IMU moves to")
    value: float | None = Field(
        None,
        ge=-2 * math.pi,
        le=2 * math.pi,
        description="encoder_fault offset, rad (with mode 'offset'), at most one turn either way",
    )
    mode: Literal["frozen", "zero", "stuck", "offset"] | None = Field(
        None, description="imu_dead: frozen|zero; encoder_fault: stuck|offset"
    )
    tether: float | None = Field(None, gt=0, le=1.0, description="imu_detached: tether length, m")
    angle_deg: float | None = Field(
        None, gt=0, le=90.0, description="imu_rotated: the mount's turn; axis_changed: the axis' bend, deg"
    )
    about: Vector3 | None = Field(
        None,
        description="imu_rotated: the turn's axis in the IMU frame (any length but zero)",
        json_schema_extra={"contains": {"not": {"const": 0}}},
    )
    meters: float | None = Field(
        None, gt=0, le=0.2, description="imu_shifted: the slide on its link, across the joint axis, m"
    )
    deg: float | None = Field(None, gt=0, le=30.0, description="backlash: the dead band's width, deg")

    @model_validator(mode="after")
    def _params_fit_kind(self) -> DamageIn:
        allowed = DAMAGE_PARAMS.get(self.kind)
        if allowed is None:
            return self
        given = [k for k in _damage_args() if getattr(self, k) is not None]
        extra = [k for k in given if k not in allowed]
        if extra:
            raise ValueError(
                f"{self.kind} takes {', '.join(allowed)}; {', '.join(extra)} "
                f"{'is' if len(extra) == 1 else 'are'} not one of them"
            )
        if self.mode is not None and self.mode not in DAMAGE_MODES.get(self.kind, ()):
            raise ValueError(f"{self.kind} mode must be one of {', '.join(DAMAGE_MODES[self.kind])}")
        if self.about is not None:
            top = max(abs(x) for x in self.about)
            if top == 0:
                raise ValueError("about must be a nonzero vector")
            # scaled to a largest component of 1: the simulator's normalisation cannot underflow
            self.about = [x / top for x in self.about]
        return self


class DamageOut(BaseModel):
    robot: str
    kind: str
    truth: dict[str, Any] = Field(description="diff JSON (docs/design.md, 'Diff JSON') of what was injected")


class FramesIn(BaseModel):
    """Frames pushed over HTTP: the FrameBatch fields as nested lists (T samples)."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={
            "examples": [
                {
                    "t": [0.0, 0.01],
                    "joint_names": ["j1", "j2"],
                    "q": [[0.0, 0.1], [0.001, 0.1]],
                    "imu_names": ["imu0"],
                    "acc": [[[0.0, 0.0, 9.81]], [[0.0, 0.01, 9.81]]],
                    "gyro": [[[0.0, 0.0, 0.0]], [[0.1, 0.0, 0.0]]],
                }
            ]
        },
    )

    t: list[Stamp] = Field(
        min_length=1,
        description=f"device time, s: finite, 0 to {T_LIMIT:.0f} (100 years), strictly increasing",
    )
    joint_names: list[PartName]
    q: list[list[Position]] = Field(description=f"(T, N) joint positions, rad, |q| <= {Q_LIMIT:g}")
    imu_names: list[PartName]
    acc: list[list[Acc3]] = Field(
        description=f"(T, K, 3) specific force, m/s², each axis within ±{ACC_LIMIT:.2f} (4 x 16 g)"
    )
    gyro: list[list[Gyro3]] = Field(
        description=f"(T, K, 3) angular rate, rad/s, each axis within ±{GYRO_LIMIT:.2f} (4 x 2000 deg/s)"
    )
    channel_names: list[PartName] = Field(
        default_factory=list, description="names of extra series on t (foot forces), unique; optional"
    )
    channels: list[list[ChannelValue]] | None = Field(
        default=None,
        description=f"(T, channels) values of the named channels on t, each within ±{CHANNEL_LIMIT:g} in the "
        "channel's own unit; given exactly when channel_names is not empty",
    )


class KeyValueOut(BaseModel):
    """diagnostic_msgs/KeyValue: both strings."""

    key: str
    value: str


class DiagnosticStatusOut(BaseModel):
    """diagnostic_msgs/DiagnosticStatus of the robot or one of its parts."""

    level: Literal[0, 1, 2, 3] = Field(
        description="0 OK, 1 WARN (pending alert, unplaced joint, status undetermined), 2 ERROR (active "
        "alert: damage), 3 STALE (silent IMU, robot without frames)"
    )
    name: str = Field(
        description="bodyhealth/<robot> or bodyhealth/<robot>/<part> (imu:<name>, joint:<name>)"
    )
    message: str
    hardware_id: str = Field(description="the robot")
    values: list[KeyValueOut] = Field(default_factory=list)

    @classmethod
    def of(cls, d: DiagnosticStatus) -> DiagnosticStatusOut:
        return cls(
            level=d.level,  # type: ignore[arg-type]
            name=d.name,
            message=d.message,
            hardware_id=d.hardware_id,
            values=[KeyValueOut(key=k, value=v) for k, v in d.values],
        )


class DiagnosticArrayOut(BaseModel):
    """diagnostic_msgs/DiagnosticArray without its header (the bridge stamps it when it publishes)."""

    status: list[DiagnosticStatusOut]
