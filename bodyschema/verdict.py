"""Two methods, one verdict: a part of the body schema stands only where the fast method and the
sensor networks both decide it and agree.

The two methods fail differently (the fast method on exact gyro models over the motion it saw, the
networks on a learned pose per IMU), so an answer both give is worth more than either alone, and an
answer only one gives is not an answer a health monitor may act on. :func:`combine` is pure: two
:class:`~bodyschema.topology.Topology` in, a :class:`Verdict` out.

A method *decides* a part (``"joint:J"``: J's parent; ``"imu:k"``: the joint whose link carries k)
when every candidate tree it lists gives the same answer and, for the networks, their held-out test
decided it (confidence above one half, :mod:`bodyschema.network_confidence`). The fast method decides
by its own tests (a part its candidates agree on); its confidence ranks rival edges and is not its
decision. It leaves joints it saw no motion of out of its tree (placeholders on the base): while it
lists any, none of its parts stands, since the joint left out could hang anywhere.

Per part the verdict is:

* **agreed**: both decide it, with the same answer; its confidence is the larger of the two (two
  methods with different failure modes agreeing);
* **undetermined**: they disagree, or either does not decide it. Both answers are kept, and ``move``
  names the joints whose motion would tell them apart: the part's own joint, the joints on one
  answer's path from the base and not on the other's, and the joints the undecided method lists.

Example
-------
>>> a = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"}, method="fast")
>>> b = Topology({"j1": None, "j2": None}, {"i1": "j1", "i2": "j2"}, method="network")
>>> v = combine(a, b)
>>> v.parts["joint:j2"].decided, v.parts["joint:j2"].move, v.topology.unique
(False, ('j1', 'j2'), False)
>>> v.parts["imu:i1"].decided, v.parts["imu:i1"].answer
(True, 'j1')
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bodyschema.topology import Topology

__all__ = [
    "DECIDED",
    "PartVerdict",
    "Verdict",
    "alone",
    "combine",
    "contradicts",
    "decided_parts",
    "part_answer",
]

#: A method decides a part when its confidence in it is above this (and its candidates agree).
DECIDED = 0.5


@dataclass(frozen=True)
class PartVerdict:
    """One part: ``decided`` (both methods decided it and agree), the answer (the agreed one; the fast
    method's best guess otherwise), each method's answer and whether it decided it, the confidence and
    the joints to move when it is undetermined."""

    part: str
    decided: bool
    answer: str | None
    fast: str | None
    network: str | None
    fast_decided: bool
    network_decided: bool
    confidence: float
    move: tuple[str, ...] = ()

    @property
    def contradicted(self) -> bool:
        """Both methods decided the part and their answers differ: the one case where a method's
        decided answer is refuted by the other, not merely unconfirmed."""
        return self.fast_decided and self.network_decided and self.fast != self.network

    def to_json(self) -> dict[str, Any]:
        return {
            "decided": self.decided,
            "answer": self.answer,
            "fast": self.fast,
            "network": self.network,
            "fast_decided": self.fast_decided,
            "network_decided": self.network_decided,
            "confidence": round(float(self.confidence), 6),
            "move": list(self.move),
        }


@dataclass(frozen=True)
class Verdict:
    """The combined topology (the fast tree as best guess, unique only when every part is agreed)
    and every part's verdict."""

    topology: Topology
    parts: dict[str, PartVerdict]

    @property
    def undetermined_parts(self) -> list[str]:
        return [k for k, p in self.parts.items() if not p.decided]

    def to_json(self) -> dict[str, Any]:
        """The topology JSON (docs/design.md, 'Topology JSON') with a ``parts`` map of the per-part
        verdicts."""
        return self.topology.to_json() | {"parts": {k: p.to_json() for k, p in self.parts.items()}}


def part_answer(topo: Topology, part: str) -> str | None:
    """What ``topo`` says of ``part``: a joint's parent or the joint an IMU rides on (None: the base,
    or a part ``topo`` does not name)."""
    kind, name = part.split(":", 1)
    return (topo.joint_parent if kind == "joint" else topo.imu_joint).get(name)


def decided_parts(topo: Topology) -> dict[str, bool]:
    """Which parts ``topo`` decides (the module docstring's rule)."""
    parts = [f"joint:{j}" for j in topo.joint_parent] + [f"imu:{i}" for i in topo.imu_joint]
    fast = topo.method == "fast"
    if fast and topo.undetermined:
        return dict.fromkeys(parts, False)
    out = {}
    for p in parts:
        ans = part_answer(topo, p)
        sure = fast or topo.confidence.get(p, 1.0) > DECIDED
        out[p] = sure and all(part_answer(c, p) == ans for c in topo.candidates)
    return out


def _chain(topo: Topology, joint: str | None) -> set[str]:
    return set() if joint is None else set(topo.ancestors(joint))


def _move(part: str, fast: Topology, net: Topology, fd: bool, nd: bool) -> tuple[str, ...]:
    """The joints whose motion would tell the two answers to ``part`` apart."""
    kind, name = part.split(":", 1)
    fa, na = part_answer(fast, part), part_answer(net, part)
    move = _chain(fast, fa) ^ _chain(net, na)
    if kind == "joint":
        move.add(name)
    for a in (fa, na):
        if a is not None and kind == "imu":
            move.add(a)
    for topo, d in ((fast, fd), (net, nd)):
        if not d:
            move |= set(topo.undetermined)
            move |= {part_answer(c, part) for c in topo.candidates} - {None}
    return tuple(sorted(m for m in move if m is not None))


def _check_same_body(fast: Topology, net: Topology) -> None:
    if set(fast.joint_parent) != set(net.joint_parent) or set(fast.imu_joint) != set(net.imu_joint):
        raise ValueError("the two topologies name different joints or IMUs; they are not of one robot")


def alone(fast: Topology) -> dict[str, PartVerdict]:
    """Per part, what one method says while the other has not answered: ``decided`` is that method's
    own decision (its answer stands unconfirmed, never agreed), the other's answer None, and ``move``
    the joints that would decide the parts it leaves open (as :func:`combine` names them).

    >>> t = Topology({"j1": None, "j2": "j1"}, {"i1": "j1"}, method="fast", undetermined=("j2",))
    >>> p = alone(t)["joint:j2"]
    >>> p.decided, p.network, p.move
    (False, None, ('j2',))
    """
    out: dict[str, PartVerdict] = {}
    for p, d in decided_parts(fast).items():
        a, c = part_answer(fast, p), fast.confidence.get(p, 1.0)
        move = () if d else _move(p, fast, fast, False, False)
        out[p] = PartVerdict(p, d, a, a, None, d, False, float(c if d else min(c, DECIDED)), move)
    return out


def combine(fast: Topology, network: Topology) -> Verdict:
    """Per part: agreed where both methods decide it with one answer, undetermined otherwise (the
    module docstring). Raises ValueError when the two name different joints or IMUs."""
    _check_same_body(fast, network)
    fd, nd = decided_parts(fast), decided_parts(network)
    parts: dict[str, PartVerdict] = {}
    conf: dict[str, float] = {}
    for p in fd:
        fa, na = part_answer(fast, p), part_answer(network, p)
        cf, cn = fast.confidence.get(p, 1.0), network.confidence.get(p, 1.0)
        agreed = fd[p] and nd[p] and fa == na
        c = max(cf, cn) if agreed else min(cf, cn, DECIDED)
        move = () if agreed else _move(p, fast, network, fd[p], nd[p])
        parts[p] = PartVerdict(p, agreed, fa, fa, na, fd[p], nd[p], float(c), move)
        conf[p] = float(c)
    undetermined = sorted({m for v in parts.values() for m in v.move})
    others = [network] if not network.same_structure(fast) else []
    cands = [c for c in (*others, *fast.candidates, *network.candidates) if not c.same_structure(fast)]
    uniq: list[Topology] = []
    for c in cands:
        if all(not c.same_structure(u) for u in uniq):
            uniq.append(Topology(joint_parent=dict(c.joint_parent), imu_joint=dict(c.imu_joint)))
    topo = Topology(
        joint_parent=dict(fast.joint_parent),
        imu_joint=dict(fast.imu_joint),
        unique=not undetermined,
        confidence=conf,
        method="fast+network",
        seconds=fast.seconds + network.seconds,
        undetermined=tuple(j for j in fast.joint_parent if j in set(undetermined)),
        candidates=tuple(uniq) if undetermined else (),
        excitation=dict(fast.excitation),
        timing=dict(fast.timing),
        training=dict(network.training),
    )
    return Verdict(topo, parts)


def contradicts(network: Topology, fast: Topology) -> list[str]:
    """The parts both decide with different answers (none when the two name different parts): what
    makes a network answer, even an ambiguous one, a word against the fast body.

    >>> a = Topology({"j1": None, "j2": "j1"}, {"i1": "j2"}, method="fast")
    >>> b = Topology({"j1": None, "j2": None}, {"i1": "j2"}, method="network")
    >>> contradicts(b, a)
    ['joint:j2']
    """
    try:
        v = combine(fast, network)
    except ValueError:
        return []
    return [p for p, pv in v.parts.items() if pv.contradicted]
