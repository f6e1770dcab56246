"""What the monitoring worker waits on for a robot, how long it waits for the sensor networks, and what
the networks' newest answer says of a baseline they did not make.

On a busy machine the sensor networks' retrains can take many minutes (an idle-class training thread
got 29 CPU s in 7 min on a loaded 2-core host), while the fast screen answers every cycle. The worker
therefore never lets a decision wait on them unbounded: a pending structural alert waits
:func:`confirm_timeout` seconds, a baseline ``baseline_unconfirmed_seconds`` (and cycles), and each robot's
record of what it waits on (:class:`Waits`, written to the store, read by :mod:`service.status`) says
what, since when, and where the robot's retrains stand in the training queue.

>>> from bodyschema.topology import Topology
>>> from service.store import TopologyRecord
>>> a = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"})
>>> b = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j1"})
>>> base = TopologyRecord(1, "arm", 10.0, 100.0, "fast", a, "fast-unconfirmed")
>>> baseline_verdict(base, TopologyRecord(2, "arm", 20.0, 130.0, "network", b))[0]
'contradicted'
>>> baseline_verdict(base, TopologyRecord(2, "arm", 20.0, 130.0, "network", a))[0]
'agree'
>>> baseline_verdict(base, TopologyRecord(2, "arm", 20.0, 90.0, "network", b))[0]
'unconfirmed'
"""

from __future__ import annotations

import logging
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any, Protocol

from bodyschema.diff import is_ambiguous
from bodyschema.verdict import contradicts
from service.settings import Settings
from service.store import TopologyRecord

__all__ = [
    "CONFIRM_FACTOR",
    "QueueSource",
    "Waits",
    "baseline_verdict",
    "confirm_timeout",
    "queue_entries",
]

log = logging.getLogger(__name__)

#: A pending alert waits this many times the robot's expected network retrain: a retrain's wall time
#: on a shared machine scatters by about a factor two between runs (the cluster's own median of recent
#: wall times is the estimate), and one more for the retrain already queued ahead of it.
CONFIRM_FACTOR = 3.0


class QueueSource(Protocol):
    """The training queue as :class:`~service.retrain.RemoteRetrains` reports it."""

    def queue_status(self) -> list[Any]: ...


def queue_entries(remote: QueueSource | None, robot: str, now: float) -> list[dict[str, Any]]:
    """``robot``'s entries in the training queue as JSON, each with ``expected_finish`` (wall time
    ``now`` plus the entry's expected seconds to go, None when unknown); ``[]`` without a queue."""
    if remote is None:
        return []
    try:
        entries = remote.queue_status()
    except Exception:  # the queue is advice for the status page; monitoring goes on without it
        log.exception("reading the training queue failed")
        return []
    out = []
    for e in entries:
        if e.robot != robot:
            continue
        entry = e.to_json()
        left = entry.get("expected_seconds")
        out.append({**entry, "expected_finish": None if left is None else round(now + float(left), 3)})
    return out


def confirm_timeout(settings: Settings, queue: list[dict[str, Any]]) -> float:
    """Seconds a pending structural alert waits for the networks (``confirm_timeout_seconds``, or
    derived from the robot's network retrain in ``queue``: :data:`CONFIRM_FACTOR` times its expected
    seconds, at least two worker intervals, at most ``confirm_timeout_max_seconds``, which is also the
    answer while nothing is known about the retrain's time)."""
    if settings.confirm_timeout_seconds > 0:
        return float(settings.confirm_timeout_seconds)
    cap = float(settings.confirm_timeout_max_seconds)
    expected = [
        float(e["expected_seconds"])
        for e in queue
        if e.get("method") == "network" and e.get("expected_seconds") is not None
    ]
    if not expected:
        return cap
    return min(cap, max(2.0 * settings.worker_interval_seconds, CONFIRM_FACTOR * max(expected)))


def baseline_verdict(
    base: TopologyRecord | None, net: TopologyRecord | None, changed: Collection[str] = ()
) -> tuple[str, str]:
    """What the sensor networks' newest topology ``net`` says of a baseline adopted without them
    (source ``fast-unconfirmed``): ``agree``, ``contradicted`` or ``unconfirmed``, with a sentence;
    ``("", "")`` for any other baseline.

    Contradicted: ``net``, from a window that ended after the baseline's, decides a part against it
    (a unique body of another structure, or an ambiguous one whose every tree places a part
    elsewhere), on a part the robot's open structural alerts (``changed``: their parts) do not already
    say changed; there the networks' other body is the change, not the baseline's error."""
    if base is None or base.source != "fast-unconfirmed":
        return "", ""
    late = (
        "the baseline was adopted from the fast screen while the sensor networks were late; "
        "they have not answered on a window after it yet"
    )
    if (
        net is None
        or net.window_end_t is None
        or base.window_end_t is None
        or net.window_end_t < base.window_end_t
    ):
        return "unconfirmed", late
    unique = not is_ambiguous(net.topology)
    if unique and net.topology.same_structure(base.topology):
        return "agree", "the sensor networks' newest topology agrees with the fast-unconfirmed baseline"
    against = set(contradicts(net.topology, base.topology))
    if unique and not against:  # another structure, though no single part decided against it
        against = {"the body's structure"}
    if not against:
        return "unconfirmed", late
    against -= set(changed)
    if not against:
        return "unconfirmed", (
            "the baseline was adopted from the fast screen while the sensor networks were late; their "
            "newest topology differs from it as the robot's open alerts say the body changed"
        )
    return "contradicted", (
        f"the baseline (fast-unconfirmed) is contradicted by the sensor networks' topology {net.id} on "
        f"{', '.join(sorted(against))}: the alerts against it are in doubt; approve a baseline"
    )


@dataclass
class Waits:
    """What the worker waits on for one robot (stored as JSON by
    :meth:`~service.store.Store.set_waiting`): each wait's ``what``, ``since`` (wall time) and, for a
    bounded one, ``until``; the robot's retrains in the training queue."""

    waits: list[dict[str, Any]] = field(default_factory=list)
    queue: list[dict[str, Any]] = field(default_factory=list)

    def add(self, what: str, since: float, until: float | None = None) -> None:
        self.waits.append({"what": what, "since": round(since, 3), "until": until and round(until, 3)})

    def to_json(self) -> dict[str, Any]:
        return {"waits": list(self.waits), "queue": list(self.queue)}
