"""The learned body schema as exchanged with the outside: the topology JSON (docs/design.md,
'Topology JSON').

A :class:`Topology` says, for each joint, which joint it hangs under (``None`` = the base) and, for each
IMU, the joint whose child link carries it (``None`` = the base link). Estimators return it, the store
keeps it, the API and the CLI print it.

Example
-------
>>> topo = Topology(joint_parent={"j1": None, "j2": "j1"}, imu_joint={"imu0": "j1", "imu1": "j2"})
>>> topo.to_json()["joints"]["j2"]
{'parent': 'j1'}
>>> Topology.from_json(topo.to_json()) == topo
True
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

__all__ = ["Topology", "TopologyError"]


class TopologyError(ValueError):
    """A topology that is not an out-tree (cycle, unknown parent) or a malformed topology JSON."""


@dataclass(frozen=True)
class Topology:
    """Joint tree plus IMU placement, with how sure the estimator is.

    ``confidence`` maps ``"imu:<name>"`` and ``"joint:<name>"`` to a probability-like score in [0, 1].
    ``undetermined`` lists joints the data cannot decide (``insufficient_excitation``); they keep their
    best-guess parent but must not be trusted. ``candidates`` holds alternative complete answers when the
    answer is not unique (partially instrumented robots). ``timing`` is set when the encoders and the
    IMUs were logged on separate clocks (docs/recording-format.md): the IMU's estimated lag behind the
    encoders and its parts, ``{"lag_ms", "lag_unc_ms", "skew_ms", "drift_ppm", "band_hz", "at_s"}``
    (``drift_ppm`` and the lag's uncertainty ``lag_unc_ms`` only from 30 s of data or more; the lag holds at
    encoder-clock time ``at_s``; with a drift it changes away from it). ``training`` is set by the
    network methods: ``{"epochs", "converged", "loss"}``, the epochs trained, 1.0 when training stopped
    on a flat loss rather than at its epoch bound, and the last epoch's loss.
    """

    joint_parent: dict[str, str | None]
    imu_joint: dict[str, str | None]
    unique: bool = True
    confidence: dict[str, float] = field(default_factory=dict)
    method: str = ""
    seconds: float = 0.0
    undetermined: tuple[str, ...] = ()
    candidates: tuple[Topology, ...] = ()
    excitation: dict[str, float] = field(default_factory=dict)
    timing: dict[str, float] = field(default_factory=dict)
    training: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.check()

    def check(self) -> None:
        """Raise :class:`TopologyError` unless the joints form an out-tree rooted at the base."""
        joints = self.joint_parent
        for j, p in joints.items():
            if p is not None and p not in joints:
                raise TopologyError(f"joint {j!r} hangs under unknown joint {p!r}")
        for imu, j in self.imu_joint.items():
            if j is not None and j not in joints:
                raise TopologyError(f"IMU {imu!r} rides unknown joint {j!r}")
        for j in joints:
            seen: set[str] = set()
            cur: str | None = j
            while cur is not None:
                if cur in seen:
                    raise TopologyError(f"joint {j!r} is on a cycle")
                seen.add(cur)
                cur = joints[cur]

    # ------------------------------------------------------------ queries
    def ancestors(self, joint: str) -> list[str]:
        """Joints from ``joint`` up to the base, ``joint`` first."""
        out: list[str] = []
        cur: str | None = joint
        while cur is not None:
            out.append(cur)
            cur = self.joint_parent[cur]
        return out

    def children(self, joint: str | None) -> list[str]:
        """Joints mounted directly under ``joint`` (None = on the base)."""
        return sorted(j for j, p in self.joint_parent.items() if p == joint)

    def subtree(self, joint: str) -> list[str]:
        """``joint`` and every joint below it."""
        out = [joint]
        for c in self.children(joint):
            out.extend(self.subtree(c))
        return out

    def same_structure(self, other: Topology) -> bool:
        """True when joint parents and IMU placement agree (confidence, timing ignored)."""
        return self.joint_parent == other.joint_parent and self.imu_joint == other.imu_joint

    # --------------------------------------------------------------- JSON
    def to_json(self) -> dict[str, Any]:
        """The topology JSON (docs/design.md, 'Topology JSON'): plain dicts, ready for ``json.dumps``."""
        out: dict[str, Any] = {
            "joints": {j: {"parent": p} for j, p in self.joint_parent.items()},
            "imus": dict(self.imu_joint),
            "unique": self.unique,
            "confidence": {k: round(float(v), 6) for k, v in self.confidence.items()},
            "method": self.method,
            "seconds": round(float(self.seconds), 6),
        }
        if self.undetermined:
            out["insufficient_excitation"] = list(self.undetermined)
        if self.candidates:
            out["candidates"] = [
                {"joints": {j: {"parent": p} for j, p in c.joint_parent.items()}, "imus": dict(c.imu_joint)}
                for c in self.candidates
            ]
        if self.excitation:
            out["excitation"] = {k: round(float(v), 6) for k, v in self.excitation.items()}
        if self.timing:
            out["timing"] = {k: round(float(v), 4) for k, v in self.timing.items()}
        if self.training:
            out["training"] = {k: round(float(v), 6) for k, v in self.training.items()}
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Topology:
        """Parse the topology JSON (docs/design.md, 'Topology JSON'); raise :class:`TopologyError` when
        malformed."""
        try:
            joints = {
                str(j): (None if v.get("parent") is None else str(v["parent"]))
                for j, v in data["joints"].items()
            }
            imus = {str(i): (None if j is None else str(j)) for i, j in data["imus"].items()}
            cands = tuple(
                cls(
                    joint_parent={str(j): v.get("parent") for j, v in c["joints"].items()},
                    imu_joint=dict(c["imus"]),
                )
                for c in data.get("candidates", [])
            )
            return cls(
                joint_parent=joints,
                imu_joint=imus,
                unique=bool(data.get("unique", True)),
                confidence={str(k): float(v) for k, v in data.get("confidence", {}).items()},
                method=str(data.get("method", "")),
                seconds=float(data.get("seconds", 0.0)),
                undetermined=tuple(data.get("insufficient_excitation", ())),
                candidates=cands,
                excitation={str(k): float(v) for k, v in data.get("excitation", {}).items()},
                timing={str(k): float(v) for k, v in data.get("timing", {}).items()},
                training={str(k): float(v) for k, v in data.get("training", {}).items()},
            )
        except (KeyError, AttributeError, TypeError, ValueError) as err:
            if isinstance(err, TopologyError):
                raise
            raise TopologyError(f"malformed topology JSON: {err}") from err

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)
