"""Alert hysteresis and confirmation: a finding is a *pending* alert the first cycle it is seen, becomes
*active* once it held M cycles (and, for the findings the sensor networks judge, once they confirmed it
or did not answer in time), and clears only after it has been gone M cycles.

One learned tree per cycle is a noisy measurement; without hysteresis a borderline IMU would raise and
clear an alert every few seconds. The tracker is a small state machine per ``(robot, kind, part)``:

``absent --seen--> pending --seen M in a row (and confirmed)--> active --gone M in a row--> resolved``

A pending finding is stored at once (an operator sees what the fast screen saw); one that misses a
cycle starts its count over and is resolved once gone M cycles in a row, so alternating input leaves
one pending alert and never raises (or clears) an active one. With the sensor networks on, the worker
passes :class:`Evidence`: findings ``waiting`` for their confirmation stay pending until the networks
confirm them (``confirmed``: active, ``confirmed=True``), withdraw them (``withdrawn``: resolved at
once, with the reason), or ``timeout`` seconds pass since first seen: then the fast screen's finding
stands, active with ``confirmed=False`` and why. Findings that are not damage
(``insufficient_excitation``) never become alerts. The tracker holds no I/O: the worker applies the
:class:`Transition` list it returns to the store.

Example
-------
>>> from bodyschema.findings import Finding
>>> tr = AlertTracker(m=2)
>>> f = Finding("imu_dead", imu="imu3")
>>> [t.state for t in tr.update("r1", [f])], [t.state for t in tr.update("r1", [f])]
(['pending'], ['active'])
>>> tr.update("r1", []), [t.state for t in tr.update("r1", [])]
([], ['resolved'])
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from bodyschema.findings import ALERT_KINDS, Finding

__all__ = ["AlertKey", "AlertTracker", "Evidence", "PartKey", "Transition"]

#: ``(robot, kind, part)``; part is ``imu:<name>`` or ``joint:<name>``.
AlertKey = tuple[str, str, str]
#: ``(kind, part)`` of one robot's finding.
PartKey = tuple[str, str]


@dataclass(frozen=True)
class Evidence:
    """What one cycle knows beyond the findings themselves (module doc); the default judges by
    hysteresis alone, as without the sensor networks.

    ``now`` is the cycle's wall time; ``waiting`` the findings whose network confirmation is awaited
    (``why``: what they wait on, for the pending alert's note), ``confirmed`` those the networks
    confirmed, ``withdrawn`` those they saw no change for (with the reason); ``timeout`` the seconds a
    finding waits before it stands unconfirmed. ``rejudge``: this is the robot's first full window
    since the tracker was restored after a restart, so a restored alert not seen in it is resolved now.
    """

    now: float = 0.0
    waiting: frozenset[PartKey] = frozenset()
    confirmed: frozenset[PartKey] = frozenset()
    withdrawn: Mapping[PartKey, str] = field(default_factory=dict)
    timeout: float = math.inf
    why: str = ""
    rejudge: bool = False


@dataclass
class _Track:
    finding: Finding
    since: float = 0.0
    seen: int = 0
    gone: int = 0
    active: bool = False
    confirmed: bool | None = None
    #: read back from the store after a restart, not yet judged on a window of this run
    restored: bool = False


@dataclass(frozen=True)
class Transition:
    """A change the store must record: ``state`` is ``"pending"`` (seen), ``"active"`` (raise, or a
    raised alert the networks confirmed since) or ``"resolved"`` (clear); ``confirmed`` and ``note``
    as the store keeps them (:mod:`service.store.alerts`)."""

    robot: str
    kind: str
    part: str
    state: str
    finding: Finding
    confirmed: bool | None = None
    note: str = ""

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

    def restore(
        self,
        robot: str,
        findings: Iterable[Finding],
        *,
        pending: bool = False,
        since: float = 0.0,
        confirmed: bool | None = None,
    ) -> None:
        """Mark findings as already active (or ``pending``, first seen at ``since``): alerts read back
        from the store after a restart, judged again on the robot's first full window (:class:`Evidence`
        ``rejudge``)."""
        with self._lock:
            for f in findings:
                self._tracks[(robot, f.kind, f.part)] = _Track(
                    f,
                    since=since,
                    seen=1 if pending else self.m,
                    active=not pending,
                    confirmed=confirmed,
                    restored=True,
                )

    def update(
        self,
        robot: str,
        findings: Iterable[Finding],
        hold: Iterable[str] = (),
        evidence: Evidence | None = None,
    ) -> list[Transition]:
        """Feed one cycle's findings for ``robot``; return the alerts seen, raised or resolved by it.

        ``hold`` names kinds this cycle could not judge (e.g. placement findings from an ambiguous
        estimate): their tracks are left as they are instead of counting the cycle as "gone".
        """
        ev = evidence or Evidence()
        held = set(hold)
        now = {(robot, f.kind, f.part): f for f in findings if f.kind in ALERT_KINDS}
        out: list[Transition] = []
        with self._lock:
            for key, f in now.items():
                out.extend(self._seen(key, f, ev))
            for key in [k for k in self._tracks if k[0] == robot and k not in now]:
                tr = self._tracks[key]
                why = ev.withdrawn.get((key[1], key[2]))
                if why is not None:
                    del self._tracks[key]
                    out.append(Transition(*key, "resolved", tr.finding, tr.confirmed, f"withdrawn: {why}"))
                    continue
                if key[1] in held:
                    continue
                if tr.restored and ev.rejudge:
                    del self._tracks[key]
                    note = "not seen in the first full window after the service restarted"
                    out.append(Transition(*key, "resolved", tr.finding, tr.confirmed, note))
                    continue
                tr.seen = 0  # a pending finding that misses a cycle starts its count over
                tr.gone += 1
                if tr.gone >= self.m:
                    del self._tracks[key]
                    note = f"not seen for {self.m} cycles in a row"
                    out.append(Transition(*key, "resolved", tr.finding, tr.confirmed, note))
            if ev.rejudge:
                for key, tr in self._tracks.items():
                    if key[0] == robot and key[1] not in held:
                        tr.restored = False
        return out

    def _seen(self, key: AlertKey, f: Finding, ev: Evidence) -> list[Transition]:
        """One sighting of ``key``'s finding: the transition it makes, if any."""
        tr = self._tracks.get(key)
        new = tr is None
        if tr is None:
            tr = self._tracks[key] = _Track(f, since=ev.now)
        tr.finding, tr.restored = f, False
        tr.seen += 1
        tr.gone = 0
        pk = (key[1], key[2])
        if pk in ev.waiting:
            waited = ev.now - tr.since
            if not tr.active and tr.seen >= self.m and waited >= ev.timeout:
                tr.active, tr.confirmed = True, False
                note = (
                    f"unconfirmed: {ev.why or 'the sensor networks'} did not answer within "
                    f"{ev.timeout:.0f} s; the fast screen's finding stands"
                )
                return [Transition(*key, "active", f, False, note)]
            if new:
                note = f"waiting for confirmation by {ev.why or 'the sensor networks'}"
                return [Transition(*key, "pending", f, None, note)]
            return []
        conf = True if pk in ev.confirmed else None
        if not tr.active and tr.seen >= self.m:
            tr.active, tr.confirmed = True, conf
            note = "confirmed by the sensor networks" if conf else f"seen {tr.seen} cycles in a row"
            return [Transition(*key, "active", f, conf, note)]
        if tr.active and conf and tr.confirmed is not True:
            tr.confirmed = True
            return [Transition(*key, "active", f, True, "confirmed by the sensor networks")]
        if new and not tr.active:
            return [Transition(*key, "pending", f, None, f"seen; raised after {self.m} cycles in a row")]
        return []

    def rejudge(self, robot: str) -> None:
        """Mark ``robot``'s tracks to be judged again on its next full window (:class:`Evidence`
        ``rejudge``), as after a restart: e.g. when its device clock went back."""
        with self._lock:
            for key, tr in self._tracks.items():
                if key[0] == robot:
                    tr.restored = True

    def forget(self, robot: str) -> None:
        """Drop every track of ``robot`` (e.g. after an operator approves a new baseline)."""
        with self._lock:
            for key in [k for k in self._tracks if k[0] == robot]:
                del self._tracks[key]

    def since(self, robot: str) -> dict[PartKey, float]:
        """When each of ``robot``'s tracked findings was first seen (``Evidence.now`` of that cycle)."""
        with self._lock:
            return {(k[1], k[2]): t.since for k, t in self._tracks.items() if k[0] == robot}

    def active(self, robot: str | None = None) -> list[AlertKey]:
        with self._lock:
            return sorted(k for k, t in self._tracks.items() if t.active and (robot is None or k[0] == robot))

    def pending(self, robot: str | None = None) -> list[AlertKey]:
        with self._lock:
            return sorted(
                k for k, t in self._tracks.items() if not t.active and (robot is None or k[0] == robot)
            )
