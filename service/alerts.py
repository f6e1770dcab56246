"""Alert hysteresis: a finding becomes an alert only after it holds M cycles, and the alert clears only
after the finding has been gone M cycles.

One learned tree per cycle is a noisy measurement; without hysteresis a borderline IMU would raise and
clear an alert every few seconds. The tracker is a small state machine per ``(robot, kind, part)``:

``absent --seen--> pending --seen M in a row--> active --gone M in a row--> resolved``

A pending finding that misses one cycle starts over; an active alert that is seen again resets its
"gone" count. Alternating input therefore never raises (and never clears) anything. Findings that are
not damage (``insufficient_excitation``) never become alerts. The tracker holds no I/O: the worker
applies the :class:`Transition` list it returns to the store.

Example
-------
>>> from bodyschema.findings import Finding
>>> tr = AlertTracker(m=2)
>>> f = Finding("imu_dead", imu="imu3")
>>> tr.update("r1", [f]), [t.state for t in tr.update("r1", [f])]
([], ['active'])
>>> tr.update("r1", []), [t.state for t in tr.update("r1", [])]
([], ['resolved'])
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from dataclasses import dataclass, field

from bodyschema.findings import ALERT_KINDS, Finding

__all__ = ["AlertKey", "AlertTracker", "Transition"]

#: ``(robot, kind, part)``; part is ``imu:<name>`` or ``joint:<name>``.
AlertKey = tuple[str, str, str]


@dataclass
class _Track:
    finding: Finding
    seen: int = 0
    gone: int = 0
    active: bool = False


@dataclass(frozen=True)
class Transition:
    """A change the store must record: ``state`` is ``"active"`` (raise) or ``"resolved"`` (clear)."""

    robot: str
    kind: str
    part: str
    state: str
    finding: Finding

    @property
    def key(self) -> AlertKey:
        return (self.robot, self.kind, self.part)


@dataclass
class AlertTracker:
    """Per-``(robot, kind, part)`` hysteresis with ``m`` cycles to raise and ``m`` to resolve."""

    m: int = 2
    _tracks: dict[AlertKey, _Track] = field(default_factory=dict, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __post_init__(self) -> None:
        if self.m < 1:
            raise ValueError(f"hysteresis m must be >= 1, got {self.m}")

    def restore(self, robot: str, findings: Iterable[Finding]) -> None:
        """Mark findings as already active (alerts read back from the store after a restart)."""
        with self._lock:
            for f in findings:
                self._tracks[(robot, f.kind, f.part)] = _Track(f, seen=self.m, active=True)

    def update(self, robot: str, findings: Iterable[Finding], hold: Iterable[str] = ()) -> list[Transition]:
        """Feed one cycle's findings for ``robot``; return the alerts raised or resolved by it.

        ``hold`` names kinds this cycle could not judge (e.g. placement findings from an ambiguous
        estimate): their tracks are left as they are instead of counting the cycle as "gone".
        """
        held = set(hold)
        now = {(robot, f.kind, f.part): f for f in findings if f.kind in ALERT_KINDS}
        out: list[Transition] = []
        with self._lock:
            for key, f in now.items():
                tr = self._tracks.setdefault(key, _Track(f))
                tr.finding = f
                tr.seen += 1
                tr.gone = 0
                if not tr.active and tr.seen >= self.m:
                    tr.active = True
                    out.append(Transition(*key, "active", f))
            for key in [k for k in self._tracks if k[0] == robot and k not in now and k[1] not in held]:
                tr = self._tracks[key]
                if not tr.active:
                    del self._tracks[key]  # a pending finding that misses a cycle starts over
                    continue
                tr.gone += 1
                if tr.gone >= self.m:
                    del self._tracks[key]
                    out.append(Transition(*key, "resolved", tr.finding))
        return out

    def forget(self, robot: str) -> None:
        """Drop every track of ``robot`` (e.g. after an operator approves a new baseline)."""
        with self._lock:
            for key in [k for k in self._tracks if k[0] == robot]:
                del self._tracks[key]

    def active(self, robot: str | None = None) -> list[AlertKey]:
        with self._lock:
            return sorted(k for k, t in self._tracks.items() if t.active and (robot is None or k[0] == robot))

    def pending(self, robot: str | None = None) -> list[AlertKey]:
        with self._lock:
            return sorted(
                k for k, t in self._tracks.items() if not t.active and (robot is None or k[0] == robot)
            )
