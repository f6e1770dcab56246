"""What a discrepancy analysis found, as data: the causes in order and the residuals around them.

:meth:`DiscrepancyReport.to_json` gives the discrepancy JSON (docs/design.md, 'Discrepancy JSON')::

    {"residual_before": {"gyro_rms": .., "acc_rms": ..},
     "causes": [{"effect": "time_offset", "params": {"seconds": 0.0035}, "gain": 0.29, ...}],
     "residual_after": {..}, "held_out": {..}}

Gains are fractions of the ideal model's held-out residual energy (normalised per channel), measured
on held-out time blocks only.

Example
-------
>>> r = DiscrepancyReport(residual_before={"gyro_rms": 0.1, "acc_rms": 0.5}, causes=[
...     Cause("gyro_bias", {"vector": [0.1, 0.0, 0.0]}, {"vector": [0.001, 0.0, 0.0]}, gain=0.9, p_value=1e-6,
...           signature="constant gyro residual", explained=0.95)],
...     residual_after={"gyro_rms": 0.01, "acc_rms": 0.5}, held_out={"blocks": 6})
>>> r.names
['gyro_bias']
>>> r.to_json()["causes"][0]["params"]
{'vector': [0.1, 0.0, 0.0]}
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Cause", "DiscrepancyReport", "JointCause"]


@dataclass(frozen=True)
class Cause:
    """One named cause: the effect, its fitted parameters with standard errors, and its held-out gain.

    ``gain``: drop of the held-out score when the effect joined the model (fraction of the ideal
    model's residual energy); ``p_value``: one-sided paired t-test of that drop over the held-out
    blocks; ``signature``: the residual pattern that pointed to it; ``explained``: the fraction of the
    then-remaining held-out residual its linearised signature explained when it was screened.
    """

    effect: str
    params: dict[str, object]
    uncertainty: dict[str, object]
    gain: float
    p_value: float
    signature: str
    explained: float
    block_gains: list[float] = field(default_factory=list)
    #: 95 % interval of each parameter (the effect's vector layout), from the block-robust evidence.
    interval: list[list[float]] = field(default_factory=list)

    def to_json(self) -> dict[str, object]:
        return {
            "effect": self.effect,
            "params": self.params,
            "uncertainty": self.uncertainty,
            "gain": round(float(self.gain), 6),
            "p_value": float(f"{self.p_value:.3g}"),
            "signature": self.signature,
            "explained": round(float(self.explained), 4),
            "block_gains": [round(float(g), 6) for g in self.block_gains],
            "interval": [[float(f"{lo:.6g}"), float(f"{hi:.6g}")] for lo, hi in self.interval],
        }


@dataclass(frozen=True)
class JointCause:
    """Effects this recording cannot tell apart, named together with their joint value.

    Their signatures overlap so much here (``correlation``, the largest canonical correlation of a
    pair of them given the rest of the model, above ``cut``:
    :mod:`bodyschema.discrepancy.separability`) that naming one alone would give it the others'
    share with an interval that ignores them. ``effects``: the group in library order; ``named``: the
    ones the selection had named; ``params``/``interval``/``uncertainty``: the joint value in the
    first effect's parameters (its change takes up the others'), fitted with the first in the model
    and the others absent; ``maps``: per other effect, the change of the first that takes up a unit
    change of it on this recording (the joint value is ``first + sum maps[e] @ (e - its null)``);
    ``separate_by``: the motion that would tell them apart.
    """

    effects: tuple[str, ...]
    named: tuple[str, ...]
    params: dict[str, object]
    uncertainty: dict[str, object]
    interval: list[list[float]]
    correlation: float
    cut: float
    maps: dict[str, list[list[float]]]
    separate_by: str
    gain: float = 0.0
    p_value: float = float("nan")

    @property
    def label(self) -> str:
        """The joint name, ``"acc_bias or gravity"``."""
        return " or ".join(self.effects)

    def to_json(self) -> dict[str, object]:
        return {
            "effect": self.label,
            "effects": list(self.effects),
            "named": list(self.named),
            "parametrization": self.effects[0],
            "params": self.params,
            "uncertainty": self.uncertainty,
            "interval": [[float(f"{lo:.6g}"), float(f"{hi:.6g}")] for lo, hi in self.interval],
            "correlation": round(float(self.correlation), 4),
            "cut": round(float(self.cut), 4),
            "maps": {e: [[float(f"{x:.6g}") for x in row] for row in m] for e, m in self.maps.items()},
            "separate_by": self.separate_by,
            "gain": round(float(self.gain), 6),
            "p_value": float(f"{self.p_value:.3g}"),
        }


@dataclass(frozen=True)
class DiscrepancyReport:
    """The outcome of :func:`bodyschema.discrepancy.analyze` (see the module docstring for the JSON)."""

    residual_before: dict[str, object]
    causes: list[Cause]
    residual_after: dict[str, object]
    held_out: dict[str, object]
    params: dict[str, dict[str, object]] = field(default_factory=dict)
    structure_before: dict[str, object] = field(default_factory=dict)
    structure_after: dict[str, object] = field(default_factory=dict)
    screening: list[dict[str, float]] = field(default_factory=list)
    #: Every effect's test on every channel in the final model (:class:`~bodyschema.discrepancy.
    #: evidence.Evidence` as JSON): the named ones given the others, the rest as candidates.
    evidence: list[dict[str, object]] = field(default_factory=list)
    settings: dict[str, object] = field(default_factory=dict)
    meta: dict[str, object] = field(default_factory=dict)
    #: Pairs of effects named together: the data fix their joint value, not the split
    #: (:class:`JointCause`); neither member is among :attr:`causes`.
    joint: list[JointCause] = field(default_factory=list)
    #: The prepared data the analysis ran on (for plots; not part of the JSON).
    problem: object | None = field(default=None, repr=False, compare=False)

    @property
    def names(self) -> list[str]:
        """The named causes, in the order they were found."""
        return [c.effect for c in self.causes]

    @property
    def joint_names(self) -> list[str]:
        """The joint names (``"acc_bias or gravity"``) of the pairs this recording cannot separate."""
        return [j.label for j in self.joint]

    @property
    def stated(self) -> set[str]:
        """Every effect the report names, alone or as a member of a joint name."""
        return set(self.names) | {e for j in self.joint for e in j.effects}

    def cause(self, effect: str) -> Cause | None:
        """The cause for ``effect``, or None when it was not named (alone)."""
        return next((c for c in self.causes if c.effect == effect), None)

    def joint_cause(self, effect: str) -> JointCause | None:
        """The joint name ``effect`` is a member of, or None."""
        return next((j for j in self.joint if effect in j.effects), None)

    def detection_limit(self, effect: str) -> float | None:
        """The smallest change of ``effect`` this recording reveals (its most sensitive channel), or
        None when the effect was not tested (not in the library analysed, or touching no channel)."""
        limits = [
            float(e["detection_limit"])
            for e in self.evidence
            if e["effect"] == effect and e["channel"] != "both"
        ]
        return min(limits) if limits else None

    def to_json(self) -> dict[str, object]:
        """The discrepancy JSON (docs/design.md, 'Discrepancy JSON'), plus residual structure, screening and
        settings."""
        return {
            "residual_before": self.residual_before,
            "causes": [c.to_json() for c in self.causes],
            "joint": [j.to_json() for j in self.joint],
            "residual_after": self.residual_after,
            "held_out": self.held_out,
            "params": self.params,
            "structure_before": self.structure_before,
            "structure_after": self.structure_after,
            "screening": self.screening,
            "evidence": self.evidence,
            "settings": self.settings,
            "meta": self.meta,
        }
