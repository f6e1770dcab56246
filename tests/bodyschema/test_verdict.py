"""combine(): a part stands only where both methods decide it and agree."""

from __future__ import annotations

import pytest

from bodyschema.topology import Topology
from bodyschema.verdict import combine, decided_parts

JOINTS = {"a": None, "b": "a", "c": "b"}
IMUS = {"i1": "a", "i2": "b", "i3": "c"}


def _topo(method: str, joints: dict | None = None, imus: dict | None = None, **kw: object) -> Topology:
    return Topology(dict(joints or JOINTS), dict(imus or IMUS), method=method, **kw)


def _all_sure(joints: dict | None = None, imus: dict | None = None) -> dict[str, float]:
    return {f"joint:{j}": 0.999 for j in joints or JOINTS} | {f"imu:{i}": 0.999 for i in imus or IMUS}


def test_agreement_everywhere_is_one_unique_answer() -> None:
    v = combine(_topo("fast"), _topo("network", confidence=_all_sure()))
    assert v.topology.unique and v.topology.undetermined == () and v.undetermined_parts == []
    assert v.topology.same_structure(_topo("fast"))
    assert v.parts["joint:c"].decided and v.parts["joint:c"].answer == "b"
    assert v.topology.confidence["joint:c"] == pytest.approx(1.0)  # the fast answer's default
    assert v.topology.method == "fast+network"


def test_a_disagreement_is_undetermined_with_both_answers_and_the_joints_to_move() -> None:
    net = {"a": None, "b": "a", "c": "a"}
    v = combine(_topo("fast"), _topo("network", joints=net, confidence=_all_sure(net)))
    p = v.parts["joint:c"]
    assert not p.decided and (p.fast, p.network) == ("b", "a")
    assert p.move == ("b", "c")  # c itself, and b: on the fast answer's path, not on the network's
    assert not v.topology.unique and set(v.topology.undetermined) == {"b", "c"}
    assert v.topology.confidence["joint:c"] <= 0.5
    assert any(c.joint_parent["c"] == "a" for c in v.topology.candidates)
    assert v.parts["imu:i3"].decided  # both put i3 on c
    assert v.to_json()["parts"]["joint:c"]["move"] == ["b", "c"]


def test_a_part_the_networks_did_not_decide_is_undetermined_even_when_they_agree() -> None:
    conf = _all_sure() | {"imu:i2": 0.5}
    v = combine(_topo("fast"), _topo("network", confidence=conf, unique=False, undetermined=("b",)))
    p = v.parts["imu:i2"]
    assert not p.decided and p.fast_decided and not p.network_decided
    assert p.fast == p.network == "b" and "b" in p.move
    assert v.parts["joint:b"].decided  # confident and agreed


def test_a_fast_answer_with_unmoved_joints_decides_nothing() -> None:
    fast = _topo("fast", undetermined=("c",), unique=True)
    assert not any(decided_parts(fast).values())
    v = combine(fast, _topo("network", confidence=_all_sure()))
    assert not v.topology.unique and v.undetermined_parts == list(v.parts)
    assert all("c" in p.move for p in v.parts.values())


def test_candidates_that_disagree_leave_a_part_open() -> None:
    alt = _topo("", joints={"a": None, "b": None, "c": "b"})
    fast = _topo("fast", unique=False, candidates=(alt,))
    d = decided_parts(fast)
    assert not d["joint:b"] and d["joint:c"] and d["imu:i1"]
    v = combine(fast, _topo("network", confidence=_all_sure()))
    assert not v.parts["joint:b"].decided and v.parts["joint:b"].move


def test_every_undetermined_part_names_joints_to_move() -> None:
    net = {"a": None, "b": None, "c": "b"}
    imus = {"i1": "a", "i2": None, "i3": "c"}
    v = combine(_topo("fast"), _topo("network", joints=net, imus=imus, confidence=_all_sure(net, imus)))
    assert v.undetermined_parts
    assert all(v.parts[k].move for k in v.undetermined_parts)
    assert v.parts["imu:i2"].move == ("a", "b")  # the fast path to i2, which the base lacks


def test_robots_that_differ_are_refused() -> None:
    with pytest.raises(ValueError, match="not of one robot"):
        combine(_topo("fast"), _topo("network", imus={"i1": "a", "i2": "b"}))
