"""Typed differences between a baseline body and the current one: the diff JSON (docs/design.md,
'Diff JSON').

Example
-------
>>> f = Finding(kind="imu_moved", imu="imu3", from_="j2", to="j4", confidence=0.97)
>>> Diff(findings=(f,)).to_json()["findings"][0]["from"]
'j2'
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["ALERT_KINDS", "DAMAGE_KINDS", "FINDING_KINDS", "KINEMATIC_KINDS", "Diff", "Finding"]

#: Kinds that are damage. ``insufficient_excitation`` is a finding but not a damage.
DAMAGE_KINDS: tuple[str, ...] = (
    "imu_moved",
    "imu_detached",
    "imu_dead",
    "joint_locked",
    "encoder_fault",
    "joint_reparented",
    "link_lost",
)
#: Geometry drift on an unchanged topology (:mod:`bodyschema.kinematic_drift`); ``backlash`` is a
#: dead band grown between a joint's encoder and its link. The simulated-damage API knows only
#: :data:`DAMAGE_KINDS`.
KINEMATIC_KINDS: tuple[str, ...] = ("imu_rotated", "imu_shifted", "axis_changed", "backlash")
FINDING_KINDS: tuple[str, ...] = (*DAMAGE_KINDS, "insufficient_excitation", *KINEMATIC_KINDS)
#: Kinds the service raises as alerts: the topology's damages and the geometry drift.
ALERT_KINDS: tuple[str, ...] = (*DAMAGE_KINDS, *KINEMATIC_KINDS)


@dataclass(frozen=True)
class Finding:
    """One typed difference. ``imu`` or ``joint`` names the part; ``from_``/``to`` the old/new value.

    ``candidates`` are the other parts (``imu:<name>``/``joint:<name>`` keys, as :attr:`part`) that
    explain the data within its error model as well as the named one: the damage is decided, which
    part carries it is not, and ``detail`` says what motion would decide.
    """

    kind: str
    imu: str | None = None
    joint: str | None = None
    from_: str | None = None
    to: str | None = None
    confidence: float = 1.0
    detail: str = ""
    candidates: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in FINDING_KINDS:
            raise ValueError(f"unknown finding kind {self.kind!r}; expected one of {FINDING_KINDS}")

    @property
    def part(self) -> str:
        """``imu:<name>`` or ``joint:<name>``: the key alerts are tracked under."""
        return f"imu:{self.imu}" if self.imu is not None else f"joint:{self.joint}"

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind}
        if self.imu is not None:
            out["imu"] = self.imu
        if self.joint is not None:
            out["joint"] = self.joint
        if self.from_ is not None or self.kind in ("imu_moved", "joint_reparented"):
            out["from"] = self.from_
        if self.to is not None or self.kind in ("imu_moved", "joint_reparented"):
            out["to"] = self.to
        out["confidence"] = round(float(self.confidence), 4)
        if self.detail:
            out["detail"] = self.detail
        if self.candidates:
            out["candidates"] = list(self.candidates)
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Finding:
        return cls(
            kind=d["kind"],
            imu=d.get("imu"),
            joint=d.get("joint"),
            from_=d.get("from"),
            to=d.get("to"),
            confidence=float(d.get("confidence", 1.0)),
            detail=d.get("detail", ""),
            candidates=tuple(str(c) for c in d.get("candidates", ())),
        )


@dataclass(frozen=True)
class Diff:
    """All findings of one comparison, and the three-valued answer (docs/design.md, 'Decisions'
    and 'Diff JSON').

    ``changed`` is True when any finding is a damage, None (undetermined) when there is none but
    ``reasons`` says the data cannot decide (several trees fit), and False only when the current body
    was decided uniquely and matches the baseline.

    >>> Diff().changed, Diff(reasons=("3 trees fit the data",)).changed
    (False, None)
    >>> Diff(findings=(Finding("imu_dead", imu="imu1"),), reasons=("3 trees fit",)).changed
    True
    """

    findings: tuple[Finding, ...] = ()
    #: why the comparison cannot say "no change": how many trees fit, which motion would decide
    reasons: tuple[str, ...] = ()

    @property
    def changed(self) -> bool | None:
        if any(f.kind in ALERT_KINDS for f in self.findings):
            return True
        return None if self.reasons else False

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"changed": self.changed, "findings": [f.to_json() for f in self.findings]}
        if self.reasons:
            out["reasons"] = list(self.reasons)
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Diff:
        return cls(
            findings=tuple(Finding.from_json(f) for f in d.get("findings", [])),
            reasons=tuple(str(r) for r in d.get("reasons", [])),
        )
