"""A robot's monitoring answer — ``healthy``, ``damaged`` or ``undetermined`` — from what the store holds.

The worker stores each learned topology, the baseline and the alerts; this module reads them back and
says what they add up to, with the pure :mod:`bodyschema.diff` functions, so the API and the dashboard
give the same three-valued answer as ``bodyhealth diff`` (docs/design.md, 'Decisions':
"Three answers, not two").
Nothing here writes to the store.

How the answer is decided, in this order:

1. **damaged** — the robot has *active* alerts. An alert becomes active only after its finding held
   ``alert_hysteresis_m`` worker cycles in a row, and the worker holds placement findings (``imu_moved``
   and the like) in cycles whose estimate was ambiguous, so an active alert is damage seen repeatedly on
   evidence that could decide it: that is certain enough to outrank an ambiguous current estimate (the
   answer still carries how many trees fit and what would decide). An acknowledged alert is still
   active: an ack says someone saw it, not that it was repaired. *Pending* alerts (seen, not yet
   confirmed) never make a robot damaged.
2. **undetermined** — any reason not to say "no change": nothing learned yet, no baseline yet, the
   current estimate is not unique (several trees fit), joints the window did not move enough to place
   (``insufficient_excitation``), a baseline that is itself ambiguous, pending alerts, or a difference
   from the baseline the worker has not confirmed yet. Each comes with a sentence in ``reasons``.
3. **healthy** — only when none of that holds: one tree fits, every joint was placed, and the diff
   against a unique baseline finds nothing.

Beside the answer: what the worker waits on for the robot (``waiting``: the network confirmation of a
pending alert, the networks' answer a baseline needs, each since when and until when it waits; the
robot's retrains in the training queue, ``queue``), as the worker last wrote it
(:meth:`~service.store.Store.set_waiting`), and what the sensor networks say of a baseline adopted
without them (``baseline_networks``, :func:`service.alert_path.baseline_verdict`): one they
contradict makes an otherwise healthy robot undetermined.

Two methods, one verdict (``methods``, :func:`methods_verdict`): per part of the body (``joint:J``,
``imu:k``) what the newest fast topology and the newest sensor-network topology say together
(:func:`bodyschema.verdict.combine`). While the networks have not answered (none stored, one of
other joints or IMUs, or one older than the baseline that shows another body) the parts rest on the
fast method alone, *unconfirmed*: that alone never makes a robot undetermined (the fast screen
answers every cycle, the networks may take minutes). A part both methods decide with different
answers is *contradicted*: an otherwise healthy robot is undetermined, with both answers and the
joints whose motion would decide (added to ``decide_by``).

Example
-------
>>> from bodyschema.topology import Topology
>>> a = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"})
>>> b = Topology({"j1": None, "j2": None}, {"i1": "j1", "i2": "j2"})
>>> judge("arm", a, a).status
'healthy'
>>> s = judge("arm", Topology(a.joint_parent, a.imu_joint, unique=False, candidates=(b,)), a)
>>> s.status, s.trees_fit, s.decide_by
('undetermined', 2, ('j1', 'j2'))
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

from bodyschema.diff import (
    STRUCTURAL_KINDS,
    deciding_joints,
    diff_bodies,
    is_ambiguous,
    undetermined_reasons,
    unplaced_reasons,
)
from bodyschema.findings import ALERT_KINDS, Diff
from bodyschema.topology import Topology
from bodyschema.verdict import PartVerdict, alone, combine
from service.alert_path import baseline_verdict
from service.store import AlertRecord, Store, TopologyRecord

__all__ = [
    "MAX_ALTERNATIVES",
    "PART_VERDICTS",
    "STATUSES",
    "Basis",
    "MethodsVerdict",
    "PartVerdictValue",
    "RobotStatus",
    "StatusValue",
    "contradiction_text",
    "decide_by",
    "judge",
    "methods_verdict",
    "robot_status",
    "robot_statuses",
    "trees_fit",
    "wait_text",
]

StatusValue = Literal["healthy", "damaged", "undetermined"]
STATUSES: tuple[str, ...] = ("healthy", "damaged", "undetermined")
#: A part's verdict: both methods decided it alike; only the fast method answered and decided it;
#: anything else (a method left it open, or the two contradict each other).
PART_VERDICTS: tuple[str, ...] = ("agreed", "unconfirmed", "undetermined")
PartVerdictValue = Literal["agreed", "unconfirmed", "undetermined"]
#: What a :class:`MethodsVerdict` rests on.
Basis = Literal["fast+network", "fast", ""]

#: Alternative trees carried in one answer; the count (``trees_fit``) is always complete as far as the
#: estimator listed them, the trees themselves are bounded so a badly under-instrumented robot cannot
#: blow up every poll of the dashboard.
MAX_ALTERNATIVES = 8


@dataclass(frozen=True)
class MethodsVerdict:
    """The fast method and the sensor networks on each part of the body (module doc).

    ``basis`` is ``"fast+network"`` when both answered, ``"fast"`` when the parts rest on the fast
    method alone (``note`` says why), ``""`` when the fast method has learned nothing. ``fast_id`` and
    ``network_id`` are the topologies compared; ``network_stale`` is set when the networks' newest
    topology was put aside as older than the baseline.
    """

    basis: Basis = ""
    parts: tuple[PartVerdict, ...] = ()
    note: str = ""
    fast_id: int | None = None
    network_id: int | None = None
    network_window_end_t: float | None = None
    network_stale: bool = False

    def verdict(self, p: PartVerdict) -> PartVerdictValue:
        """One of :data:`PART_VERDICTS` for ``p``."""
        if not p.decided:
            return "undetermined"
        return "agreed" if self.basis == "fast+network" else "unconfirmed"

    @property
    def contradicted(self) -> tuple[PartVerdict, ...]:
        """The parts both methods decided with different answers."""
        return tuple(p for p in self.parts if p.contradicted)

    @property
    def counts(self) -> dict[str, int]:
        """How many parts have each verdict, and how many of the undetermined ones are contradicted."""
        out = dict.fromkeys(PART_VERDICTS, 0)
        for p in self.parts:
            out[self.verdict(p)] += 1
        return out | {"contradicted": len(self.contradicted)}


@dataclass(frozen=True)
class RobotStatus:
    """The three-valued answer for one robot and everything it rests on.

    ``trees_fit`` is 1 for a unique estimate, the number of trees the estimator listed when several fit
    (the estimator lists a bounded number, so this is a lower bound for very ambiguous data), None when
    nothing was learned or the estimate says "not unique" without listing them. ``alternatives`` are the
    other fitting trees (at most :data:`MAX_ALTERNATIVES`). ``decide_by`` names the joints whose motion,
    each on its own with the others still, would decide between the trees or place an unplaced joint.
    ``topology`` is the estimate judged; ``current`` and ``baseline`` are the store's records when the
    answer was read from a store. ``network`` is the robot's newest sensor-network topology (when
    another method is judged): what the last retrain learned, and how it trained. ``waiting`` and
    ``queue`` are what the worker waits on and the robot's retrains in the training queue (module
    doc); ``baseline_networks`` what the networks say of a fast-unconfirmed baseline; ``methods`` the
    two methods' verdict per part.
    """

    robot: str
    status: StatusValue
    reasons: tuple[str, ...]
    trees_fit: int | None = None
    alternatives: tuple[Topology, ...] = ()
    decide_by: tuple[str, ...] = ()
    insufficient_excitation: tuple[str, ...] = ()
    alerts: tuple[AlertRecord, ...] = ()
    pending: tuple[AlertRecord, ...] = ()
    diff: Diff | None = None
    topology: Topology | None = None
    current: TopologyRecord | None = None
    baseline: TopologyRecord | None = None
    network: TopologyRecord | None = None
    waiting: tuple[dict[str, Any], ...] = ()
    queue: tuple[dict[str, Any], ...] = ()
    baseline_networks: str = ""
    methods: MethodsVerdict = MethodsVerdict()

    @property
    def timing(self) -> dict[str, float | None]:
        """The judged estimate's IMU-to-encoder timing (multi-rate data), non-finite values as None."""
        return _finite(self.topology.timing) if self.topology is not None else {}

    @property
    def training(self) -> dict[str, float | None]:
        """The judged estimate's training record (network methods), non-finite values as None."""
        return _finite(self.topology.training) if self.topology is not None else {}


def _finite(d: dict[str, float]) -> dict[str, float | None]:
    # JSON has no NaN: a loss that diverged is reported as unknown rather than failing the response.
    return {k: (float(v) if math.isfinite(float(v)) else None) for k, v in d.items()}


def trees_fit(topo: Topology | None) -> int | None:
    """How many trees fit: 1 when unique, the listed count when several, None when unknown.

    >>> trees_fit(Topology({"j1": None}, {"i1": "j1"}))
    1
    >>> trees_fit(Topology({"j1": None}, {"i1": "j1"}, unique=False)) is None
    True
    """
    if topo is None:
        return None
    if not is_ambiguous(topo):
        return 1
    return 1 + len(topo.candidates) if topo.candidates else None


def decide_by(topo: Topology | None) -> tuple[str, ...]:
    """Joints to move, each on its own with the others still, to decide what the data left open.

    :func:`bodyschema.diff.deciding_joints`, the joints :func:`bodyschema.diff.undetermined_reasons`
    names; none when nothing was learned.

    >>> a = Topology({"j1": None, "j2": "j1", "j3": None}, {"i1": "j1", "i2": "j2"}, undetermined=("j3",))
    >>> decide_by(a)
    ('j3',)
    """
    return () if topo is None else deciding_joints(topo)


def _alert_text(a: AlertRecord) -> str:
    f = a.finding or {}
    if a.kind in ("imu_moved", "joint_reparented"):
        where = f" ({f.get('from') or 'base'} → {f.get('to') or 'base'})"
    else:
        where = f" ({f['detail']})" if f.get("detail") else ""
    word = " [unconfirmed by the sensor networks]" if a.confirmed is False else ""
    return f"{a.kind} on {a.part}{where}{word}"


def _when(t: float | None) -> str:
    """A wall time as UTC, to the second."""
    return "?" if t is None else time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(float(t)))


def wait_text(w: dict[str, Any]) -> str:
    """One wait of the worker's record as a sentence.

    >>> wait_text({"what": "baseline: the sensor networks' answer", "since": 60.0})
    "waiting on baseline: the sensor networks' answer since 1970-01-01 00:01:00 UTC"
    """
    until = f" (at most until {_when(w['until'])})" if w.get("until") is not None else ""
    return f"waiting on {w.get('what', '?')} since {_when(w.get('since'))}{until}"


def _finding_text(f: dict[str, Any]) -> str:
    part = f.get("imu") or f.get("joint") or "?"
    if f.get("candidates"):  # the damage is decided, its part is not
        part = " or ".join([part, *(str(c).split(":", 1)[-1] for c in f["candidates"])])
    if "to" in f:
        return f"{f['kind']} {part} ({f.get('from') or 'base'} → {f.get('to') or 'base'})"
    return f"{f['kind']} {part}"


def _topology(rec: TopologyRecord | Topology | None) -> Topology | None:
    return rec.topology if isinstance(rec, TopologyRecord) else rec


def judge(
    robot: str,
    current: TopologyRecord | Topology | None,
    baseline: TopologyRecord | Topology | None,
    active: Sequence[AlertRecord] = (),
    pending: Sequence[AlertRecord] = (),
) -> RobotStatus:
    """The answer from the newest learned topology, the baseline and the robot's alerts (pure).

    Records or bare topologies are accepted, so the rule can be checked without a store; the rule and
    its order are in the module doc.
    """
    cur, base = _topology(current), _topology(baseline)
    cur_rec = current if isinstance(current, TopologyRecord) else None
    base_rec = baseline if isinstance(baseline, TopologyRecord) else None
    diff = diff_bodies(base, cur) if cur is not None and base is not None else None
    common: dict[str, Any] = {
        "robot": robot,
        "trees_fit": trees_fit(cur),
        "alternatives": tuple(cur.candidates[:MAX_ALTERNATIVES]) if cur is not None else (),
        "decide_by": decide_by(cur),
        "insufficient_excitation": tuple(cur.undetermined) if cur is not None else (),
        "alerts": tuple(active),
        "pending": tuple(pending),
        "diff": diff,
        "topology": cur,
        "current": cur_rec,
        "baseline": base_rec,
    }
    ambiguous = cur is not None and is_ambiguous(cur)
    ambiguity: list[str] = [*undetermined_reasons(cur), *unplaced_reasons(cur)] if cur is not None else []

    if active:
        n = len(active)
        head = f"{n} active alert{'s' if n > 1 else ''}: " + "; ".join(_alert_text(a) for a in active)
        return RobotStatus(status="damaged", reasons=(head, *ambiguity), **common)

    reasons: list[str] = []
    if cur is None:
        reasons.append("nothing learned yet: the worker has not had a full window of this robot")
    if base is None:
        reasons.append(
            "no baseline yet, so nothing to compare with: one is adopted once the same unique tree is "
            "learned several cycles in a row, or an operator approves one"
        )
    elif is_ambiguous(base):
        reasons.append("the baseline itself is not unique: approve a body that one tree fits")
    reasons.extend(ambiguity)
    if pending:
        reasons.append(
            "seen but not yet confirmed (an alert needs several worker cycles in a row): "
            + "; ".join(_alert_text(a) + (f", {a.note}" if a.note else "") for a in pending)
        )
    if diff is not None and not ambiguous:
        # a difference already pending as an alert is reported once, above
        seen = {a.part for a in pending}
        unconfirmed = [f for f in diff.findings if f.kind in ALERT_KINDS and f.part not in seen]
        if unconfirmed:
            reasons.append(
                "the newest estimate differs from the baseline, not yet confirmed by the worker: "
                + "; ".join(_finding_text(f.to_json()) for f in unconfirmed)
            )
    if reasons:
        return RobotStatus(status="undetermined", reasons=tuple(reasons), **common)
    return RobotStatus(
        status="healthy",
        reasons=("one tree fits the data, every joint is placed, and it matches the baseline",),
        **common,
    )


def robot_status(store: Store, robot: str, method: str | None = None) -> RobotStatus:
    """Read the robot's newest topology (of ``method``; default the fast estimator's, else any), its
    baseline and its open alerts from ``store`` and :func:`judge` them. Raises
    :class:`~service.store.UnknownRobot` for a robot the store does not know."""
    cur = store.latest_topology(robot, method=method or "fast")
    if cur is None and method is None:
        cur = store.latest_topology(robot)
    fast = cur if method in (None, "fast") else store.latest_topology(robot, method="fast")
    if fast is not None and fast.method != "fast":
        fast = None  # the fallback to any method: no fast topology was learned
    return _judged(
        robot,
        cur,
        store.baseline(robot),
        store.alerts(robot, active=True),
        store.alerts(robot, state="pending"),
        store.latest_topology(robot, method="network"),
        store.waiting(robot).get(robot, {}),
        fast,
    )


def _stale(net: TopologyRecord, base: TopologyRecord | None) -> bool:
    """The networks' topology is older than the baseline (window ends where both have one, else wall
    times: an operator's approval has no window) and shows another body: it was learned of the body
    before the one the baseline records (a repair, a re-approval). One of the baseline's body is not
    stale: a baseline adopted from the networks' answer is stamped after the answer it came from."""
    if base is None or net.topology.same_structure(base.topology):
        return False
    if net.window_end_t is not None and base.window_end_t is not None:
        return net.window_end_t < base.window_end_t
    return net.wall_time < base.wall_time


def _fast_alone(
    fast: TopologyRecord, net: TopologyRecord | None, base: TopologyRecord | None
) -> tuple[str, bool]:
    """Why the networks' topology ``net`` cannot be set beside ``fast`` ("" when it can), and
    whether that is because it is stale."""
    if net is None:
        return "the sensor networks have not answered yet", False
    if _stale(net, base):
        return (
            f"the sensor networks' newest topology {net.id} is stale: older than the baseline, it "
            "shows another body",
            True,
        )
    f, n = fast.topology, net.topology
    if set(f.joint_parent) != set(n.joint_parent) or set(f.imu_joint) != set(n.imu_joint):
        return f"the sensor networks' newest topology {net.id} names other joints or IMUs", False
    return "", False


def methods_verdict(
    fast: TopologyRecord | None, net: TopologyRecord | None, base: TopologyRecord | None = None
) -> MethodsVerdict:
    """The two methods' verdict per part from the newest fast topology ``fast`` and the newest
    network topology ``net``, ``base`` the baseline (module doc)."""
    if fast is None:
        return MethodsVerdict(note="the fast method has learned nothing yet: no part is judged")
    why, stale = _fast_alone(fast, net, base)
    net_id, net_end = (net.id, net.window_end_t) if net is not None else (None, None)
    if why:
        parts = tuple(alone(fast.topology).values())
        note = f"the verdict rests on the fast method alone and is unconfirmed: {why}"
        return MethodsVerdict("fast", parts, note, fast.id, net_id, net_end, stale)
    assert net is not None
    parts = tuple(combine(fast.topology, net.topology).parts.values())
    v = MethodsVerdict("fast+network", parts, "", fast.id, net_id, net_end)
    c = v.counts
    note = (
        f"fast topology {fast.id} and network topology {net.id}: {c['agreed']} of {len(parts)} "
        f"parts agreed, {c['undetermined']} undetermined ({c['contradicted']} contradicted)"
    )
    return dataclasses.replace(v, note=note)


def _where(p: PartVerdict, answer: str | None) -> str:
    if p.part.startswith("joint:"):
        return f"parent {answer or 'base'}"
    return f"on {answer or 'the base link'}"


def contradiction_text(p: PartVerdict) -> str:
    """A contradicted part as a sentence: both answers and what would decide.

    >>> p = PartVerdict("joint:j2", False, "j1", "j1", None, True, True, 0.5, ("j1", "j2"))
    >>> contradiction_text(p)[65:]  # doctest: +ELLIPSIS
    'joint:j2 (fast: parent j1; networks: parent base): to decide, move ...: j1, j2'
    """
    return (
        f"the fast method and the sensor networks contradict each other on {p.part} "
        f"(fast: {_where(p, p.fast)}; networks: {_where(p, p.network)}): to decide, move each of "
        f"these joints on its own with the others still: {', '.join(p.move)}"
    )


def _judged(
    robot: str,
    cur: TopologyRecord | None,
    base: TopologyRecord | None,
    active: Sequence[AlertRecord],
    pending: Sequence[AlertRecord],
    net: TopologyRecord | None,
    waiting: dict[str, Any] | None = None,
    fast: TopologyRecord | None = None,
) -> RobotStatus:
    """:func:`judge`, with the newest network topology beside it when there is one, what the worker
    waits on, what the networks say of a baseline adopted without them, and the two methods' verdict
    per part on the newest fast topology ``fast`` (module doc)."""
    st = judge(robot, cur, base, active, pending)
    waits = tuple((waiting or {}).get("waits") or ())
    changed = {a.part for a in (*active, *pending) if a.kind in STRUCTURAL_KINDS}
    verdict, why = baseline_verdict(base, net, changed)
    methods = methods_verdict(fast, net, base)
    reasons = list(st.reasons)
    if why:
        reasons.append(why)
    reasons.extend(contradiction_text(p) for p in methods.contradicted)
    reasons.extend(wait_text(w) for w in waits)
    status, decide = st.status, st.decide_by
    if (verdict == "contradicted" or methods.contradicted) and status == "healthy":
        status, reasons = "undetermined", reasons[1:]  # "one tree fits ... matches the baseline" no more
    if methods.contradicted:
        decide = tuple(sorted({*decide, *(m for p in methods.contradicted for m in p.move)}))
    return dataclasses.replace(
        st,
        status=status,
        reasons=tuple(reasons),
        decide_by=decide,
        network=net,
        waiting=waits,
        queue=tuple((waiting or {}).get("queue") or ()),
        baseline_networks=verdict,
        methods=methods,
    )


def _by_robot(alerts: Sequence[AlertRecord]) -> dict[str, list[AlertRecord]]:
    """``alerts`` per robot, in their order."""
    out: dict[str, list[AlertRecord]] = {}
    for a in alerts:
        out.setdefault(a.robot, []).append(a)
    return out


def robot_statuses(
    store: Store,
    robots: Sequence[str],
    method: str | None = None,
    judged: dict[str, tuple[Any, RobotStatus]] | None = None,
) -> dict[str, RobotStatus]:
    """:func:`robot_status` of each of ``robots``, read for the whole fleet at once: six queries, where
    asking robot by robot takes five per robot (the API's robot list asks every robot's). ``robots``
    are names the store knows (as :meth:`~service.store.Store.robots` lists them).

    ``judged`` (robot -> what its answer was judged from, and the answer) keeps answers across calls:
    :func:`judge` is pure, so a robot whose records and alerts are the ones its kept answer came from
    is not judged again (after a retrain, one robot of the fleet changed; judging is a diff of two
    bodies per robot). The caller owns it and keeps it as long as it likes; it is updated here.
    """
    cur = store.latest_topologies(method or "fast")
    anyway = store.latest_topologies() if method is None else {}
    fast = cur if method in (None, "fast") else store.latest_topologies("fast")
    net = store.latest_topologies("network")
    bases = store.baselines()
    waiting = store.waiting()
    active, pending = _by_robot(store.alerts(active=True)), _by_robot(store.alerts(state="pending"))
    kept: dict[str, tuple[Any, RobotStatus]] = {} if judged is None else judged
    out: dict[str, RobotStatus] = {}
    for robot in robots:
        args = (
            cur.get(robot) or anyway.get(robot),
            bases.get(robot),
            active.get(robot, []),
            pending.get(robot, []),
            net.get(robot),
            waiting.get(robot, {}),
            fast.get(robot),
        )
        # compared, never hashed: alert records compare by value (their finding too)
        key = (
            _record_key(args[0]),
            _record_key(args[1]),
            tuple(args[2]),
            tuple(args[3]),
            _record_key(args[4]),
            args[5],
            _record_key(args[6]),
        )
        hit = kept.get(robot)
        if hit is not None and hit[0] == key:
            out[robot] = hit[1]
            continue
        out[robot] = _judged(robot, *args)
        kept[robot] = (key, out[robot])
    return out


def _record_key(rec: TopologyRecord | None) -> tuple[Any, ...] | None:
    """What tells a stored topology apart (its rows are never changed, see the store)."""
    return None if rec is None else (rec.id, rec.wall_time, rec.method, rec.source)
