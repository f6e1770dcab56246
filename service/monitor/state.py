"""What the monitoring worker remembers about one robot between cycles, and what each event forgets.

The store keeps what outlives the process (baselines, topologies, alerts, the last lag measured); a
:class:`RobotState` holds the rest, one per robot. :data:`FORGETS` and :meth:`RobotState.reset` are the
one place that says what an event forgets:

* ``approval``: an operator approved a baseline (on the request's thread, while a cycle may run): the
  fingerprints, learned on the old one. The next cycle sees the new baseline's id and forgets the rest
  (``baseline``).
* ``baseline``: the cycle compares with another baseline than the last cycle did: everything tracked
  against the old one (fingerprints, onsets, first sightings, the last findings, a re-judgement due).
* ``adopted``: the worker adopted a baseline itself: the streak that made it, and the fingerprints
  (learned again from the first window that matches it).
* ``epoch``: the robot's device clock went back: the device times (onsets, first sightings, the last
  geometry estimate's window end; stamped on the old clock they would lie in the new one's future),
  the lag (searched from zero again) and the fingerprints (a restarted robot's encoders may count from
  other offsets); its alerts are judged again on the new epoch's first full window.
* ``restart``: a new worker remembers nothing; the alerts it reads back from the store are judged again
  on the robot's first full window.

The worker's :class:`~service.alerts.AlertTracker` keeps the alerts' hysteresis; the worker tells it
alongside (``forget`` on a new baseline, ``rejudge`` on a new epoch).
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from bodyschema.health import BaselineFingerprints
from bodyschema.recording import Recording
from bodyschema.topology import Topology

__all__ = ["FORGETS", "FULL_WINDOW_SHARE", "RobotState", "Streak", "full_window"]


@dataclass
class Streak:
    """The cycles in a row whose fast topology had one structure, while a robot has no baseline."""

    #: the newest topologies of the streak (at most ``baseline_repeat_k``)
    topologies: deque[Topology] = field(default_factory=deque)
    #: its length in cycles (it may outlast ``topologies`` while it waits for the networks)
    n: int = 0
    #: window end (device time) of its first cycle
    start: float | None = None
    #: window end of the cycle that first completed it while the networks did not agree with it
    since: float | None = None
    #: wall time it started waiting for the networks
    wall: float | None = None

    def add(self, topo: Topology, window_end: float, k: int) -> None:
        """One more cycle of the streak (``k`` topologies kept)."""
        self.topologies.append(topo)
        while len(self.topologies) > k:
            self.topologies.popleft()
        if self.start is None:
            self.start = window_end
        self.n += 1

    def clear(self) -> None:
        """The streak broke: nothing of it is kept."""
        self.topologies.clear()
        self.n, self.start, self.since, self.wall = 0, None, None, None


@dataclass
class RobotState:
    """Everything the worker keeps for one robot between cycles (module doc)."""

    streak: Streak = field(default_factory=Streak)
    #: each joint's encoder-to-gyro relation and each IMU's residual share on the baseline (learned
    #: state): set when a baseline is adopted, or after a restart, an approval or a new epoch from the
    #: first full window with no hole that matches the baseline
    fingerprints: BaselineFingerprints | None = None
    #: methods asked for (on demand retrains), run in the next cycle; guarded by the worker's lock
    requests: set[str] = field(default_factory=set)
    #: the (kind, part) of the previous cycle's findings (a new one asks the networks)
    findings: frozenset[tuple[str, str]] = frozenset()
    #: per (kind, part): window end of the first cycle of the current run of cycles whose fast screen
    #: showed that structural finding
    first_seen: dict[tuple[str, str], float] = field(default_factory=dict)
    #: wall time of the last network retrain the worker asked for itself
    network_asked: float | None = None
    #: per IMU: window end of the first cycle of the current run whose diff placed it elsewhere than
    #: the baseline (every later sample was recorded after the change)
    onset: dict[str, float] = field(default_factory=dict)
    #: the ``last_frame_t`` last seen and the wall time it was first seen (None: never)
    activity: tuple[float | None, float] | None = None
    #: the device clock epoch of the last cycle (None: none yet)
    epoch: int | None = None
    #: the encoder-to-IMU lag (s) of the last fast topology (None: not read from the store yet)
    lag: float | None = None
    #: the id of the baseline the last cycle compared with, once a cycle saw one (or none)
    baseline_id: int | None = None
    baseline_known: bool = False
    #: open alerts are judged again on the first full window (after a restart or a new epoch)
    rejudge: bool = False
    #: what it waits on, as last written to the store
    waits_written: dict[str, Any] | None = None
    #: the cycle and window end (device time) of its last geometry estimate (None: none yet)
    geometry_last: tuple[int, float] | None = None

    def reset(self, reason: str) -> None:
        """Forget what ``reason`` (a key of :data:`FORGETS`) forgets; the rest stays."""
        forgets, sets = FORGETS[reason]
        fresh = RobotState()
        for name in forgets:
            if name == "streak":
                self.streak.clear()
            else:
                setattr(self, name, getattr(fresh, name))
        for name, value in sets.items():
            setattr(self, name, value)


_ALL = tuple(f.name for f in dataclasses.fields(RobotState))

#: Per event (module doc): the fields it forgets (back to a new state's), and those it sets instead.
FORGETS: dict[str, tuple[tuple[str, ...], dict[str, Any]]] = {
    "approval": (("fingerprints",), {}),
    "baseline": (("fingerprints", "onset", "first_seen", "findings", "rejudge"), {}),
    "adopted": (("fingerprints", "streak"), {}),
    "epoch": (("fingerprints", "onset", "first_seen", "geometry_last"), {"lag": 0.0, "rejudge": True}),
    "restart": (_ALL, {"rejudge": True}),
}


#: The share of ``window_seconds`` a window must span for the worker's judgements: the thresholds
#: (hysteresis, drift, the floating checks) are derived for full windows.
FULL_WINDOW_SHARE = 0.8


def full_window(rec: Recording, window_seconds: float) -> bool:
    """True when ``rec`` spans at least :data:`FULL_WINDOW_SHARE` of ``window_seconds``."""
    return rec.duration >= FULL_WINDOW_SHARE * window_seconds
