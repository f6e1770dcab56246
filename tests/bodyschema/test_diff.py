"""Baseline vs current: each finding kind from synthetic topologies and signal health."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.diff import DiffThresholds, diff_bodies
from bodyschema.findings import Diff
from bodyschema.health import ImuHealth, JointHealth, SignalHealth
from bodyschema.topology import Topology

#        base
#         |
#        j1 (a1, a2)
#       /   \
#     j2     j4 (d1, d2)
#  (b1,b2)    |
#     |      j5 (e1)
#    j3 (c1, c2)
JOINTS = {"j1": None, "j2": "j1", "j3": "j2", "j4": "j1", "j5": "j4"}
IMUS = {
    "a1": "j1",
    "a2": "j1",
    "b1": "j2",
    "b2": "j2",
    "c1": "j3",
    "c2": "j3",
    "d1": "j4",
    "d2": "j4",
    "e1": "j5",
}
EXC = {j: 0.4 for j in JOINTS}
BASE = Topology(dict(JOINTS), dict(IMUS), excitation=dict(EXC))


def topo(joints: dict | None = None, imus: dict | None = None, **kw) -> Topology:
    j = dict(JOINTS)
    j.update(joints or {})
    i = dict(IMUS)
    i.update(imus or {})
    kw.setdefault("excitation", dict(EXC))
    return Topology(j, {k: v for k, v in i.items() if v != "GONE"}, **kw)


def health(
    imus: dict[str, str] | None = None,
    joints: dict[str, str] | None = None,
    excitation: dict[str, float] | None = None,
) -> SignalHealth:
    exc = dict(EXC)
    exc.update(excitation or {})
    ih = {n: ImuHealth(n, (imus or {}).get(n, "ok"), 0.3) for n in IMUS}
    jh = {n: JointHealth(n, (joints or {}).get(n, "ok"), exc[n], 0.4, 0.99) for n in JOINTS}
    return SignalHealth(ih, jh)


def kinds(d: Diff) -> list[tuple[str, str]]:
    return sorted((f.kind, f.part) for f in d.findings)


def test_identical_gives_nothing() -> None:
    assert diff_bodies(BASE, BASE).findings == ()
    assert diff_bodies(BASE, topo(), health()).findings == ()
    assert not diff_bodies(BASE, topo(), health()).changed


def test_random_identical_trees_give_nothing(rng: np.random.Generator) -> None:
    for _ in range(20):
        n = int(rng.integers(1, 8))
        names = [f"j{k}" for k in range(n)]
        parents = {
            names[k]: (None if k == 0 or rng.random() < 0.2 else names[int(rng.integers(0, k))])
            for k in range(n)
        }
        imus = {f"i{k}": names[int(rng.integers(0, n))] for k in range(int(rng.integers(1, 12)))}
        t = Topology(parents, imus)
        assert diff_bodies(t, Topology(dict(parents), dict(imus))).findings == ()


def test_imu_moved() -> None:
    d = diff_bodies(BASE, topo(imus={"c1": "j5"}, confidence={"imu:c1": 0.8}), health())
    assert kinds(d) == [("imu_moved", "imu:c1")]
    f = d.findings[0]
    assert (f.from_, f.to, f.confidence) == ("j3", "j5", 0.8)
    assert d.to_json()["findings"][0] == {
        "kind": "imu_moved",
        "imu": "c1",
        "from": "j3",
        "to": "j5",
        "confidence": 0.8,
    }


def test_imu_detached() -> None:
    d = diff_bodies(BASE, topo(imus={"d2": None}), health())
    assert kinds(d) == [("imu_detached", "imu:d2")]
    assert d.findings[0].from_ == "j4"


@pytest.mark.parametrize("state", ["zero", "frozen", "silent"])
def test_imu_dead_is_not_structure(state: str) -> None:
    # the estimator places a dead IMU anywhere (here: the base); only imu_dead must come out
    cur = topo(imus={"b1": "GONE" if state == "silent" else None})
    d = diff_bodies(BASE, cur, health(imus={"b1": state}))
    assert kinds(d) == [("imu_dead", "imu:b1")]
    assert d.findings[0].detail == state


def test_missing_imu_without_health_is_dead() -> None:
    d = diff_bodies(BASE, topo(imus={"e1": "GONE"}))
    assert kinds(d) == [("imu_dead", "imu:e1")]


def test_joint_locked() -> None:
    # j2 stops: its IMUs now read as j1's, j3 hangs under j1 in the new estimate
    cur = topo(
        joints={"j3": "j1"},
        imus={"b1": "j1", "b2": "j1"},
        undetermined=("j2",),
        excitation={**EXC, "j2": 0.001},
    )
    d = diff_bodies(BASE, cur, health(joints={"j2": "still"}, excitation={"j2": 0.001}))
    assert kinds(d) == [("joint_locked", "joint:j2")]


def test_still_joint_that_never_moved_is_not_locked() -> None:
    base = Topology(dict(JOINTS), dict(IMUS), excitation={**EXC, "j2": 0.0})
    d = diff_bodies(base, topo(), health(joints={"j2": "still"}, excitation={"j2": 0.0}))
    assert not d.changed


def test_nothing_moves_is_not_locked() -> None:
    h = health(joints={j: "still" for j in JOINTS}, excitation={j: 0.0 for j in JOINTS})
    cur = topo(undetermined=tuple(JOINTS))
    d = diff_bodies(BASE, cur, h)
    assert not d.changed
    assert {f.kind for f in d.findings} == {"insufficient_excitation"}


def test_encoder_fault_frozen() -> None:
    cur = topo(imus={"e1": "j4"}, undetermined=("j5",), excitation={**EXC, "j5": 0.0})
    d = diff_bodies(BASE, cur, health(joints={"j5": "frozen_encoder"}, excitation={"j5": 0.0}))
    assert kinds(d) == [("encoder_fault", "joint:j5")]
    assert "flat" in d.findings[0].detail


def test_encoder_fault_wrong() -> None:
    # the link turns, the encoder disagrees, but the estimate still hangs the IMUs on j4
    d = diff_bodies(BASE, topo(), health(joints={"j4": "wrong_encoder"}))
    assert kinds(d) == [("encoder_fault", "joint:j4")]


def test_frozen_encoder_scrambling_the_subtree_is_one_finding() -> None:
    # a stuck encoder high in the tree: the estimate loses every IMU below it
    cur = topo(
        joints={"j2": None, "j3": None},
        imus={"b1": None, "b2": None, "c1": None, "c2": None},
        undetermined=("j2",),
    )
    d = diff_bodies(BASE, cur, health(joints={"j2": "frozen_encoder"}, excitation={"j2": 0.0}))
    assert kinds(d) == [("encoder_fault", "joint:j2")]


def test_wrong_encoder_with_every_imu_below_lost_is_link_lost() -> None:
    cur = topo(joints={"j5": None}, imus={"d1": None, "d2": None, "e1": None})
    d = diff_bodies(BASE, cur, health(joints={"j4": "wrong_encoder"}))
    assert kinds(d) == [("link_lost", "joint:j4")]


def test_link_lost_subtree() -> None:
    # the j2 subtree broke off: its four IMUs follow nothing any more
    cur = topo(imus={"b1": None, "b2": None, "c1": None, "c2": None})
    d = diff_bodies(BASE, cur, health(joints={"j2": "unfollowed", "j3": "unfollowed"}))
    assert kinds(d) == [("link_lost", "joint:j2")]
    assert d.findings[0].from_ == "j1"


def test_link_lost_without_health() -> None:
    cur = topo(imus={"d1": None, "d2": "j1", "e1": None})
    assert kinds(diff_bodies(BASE, cur)) == [("link_lost", "joint:j4")]


def test_single_imu_leaf_lost_only_with_unfollowed_encoder() -> None:
    cur = topo(imus={"e1": None})
    assert kinds(diff_bodies(BASE, cur, health())) == [("imu_detached", "imu:e1")]
    assert kinds(diff_bodies(BASE, cur, health(joints={"j5": "unfollowed"}))) == [("link_lost", "joint:j5")]


def test_joint_reparented() -> None:
    d = diff_bodies(BASE, topo(joints={"j5": "j2"}, confidence={"joint:j5": 0.7}), health())
    assert kinds(d) == [("joint_reparented", "joint:j5")]
    assert d.to_json()["findings"][0]["from"] == "j4"
    assert d.to_json()["findings"][0]["to"] == "j2"


def test_insufficient_excitation_suppresses_dependents() -> None:
    # j3 barely moved in this window: the estimate parks its IMUs on j2; that is not a damage
    cur = topo(imus={"c1": "j2", "c2": "j2"}, undetermined=("j3",))
    d = diff_bodies(BASE, cur, health(joints={"j3": "ok"}))
    assert kinds(d) == [("insufficient_excitation", "joint:j3")]
    assert not d.changed


def test_min_confidence_filters_uncertain_moves() -> None:
    cur = topo(imus={"c1": "j5"}, confidence={"imu:c1": 0.3})
    assert diff_bodies(BASE, cur, health(), DiffThresholds(min_confidence=0.5)).findings == ()


def test_two_independent_damages_both_found() -> None:
    cur = topo(imus={"a1": None, "c1": "j4"})
    d = diff_bodies(BASE, cur, health(imus={"a1": "zero"}))
    assert kinds(d) == [("imu_dead", "imu:a1"), ("imu_moved", "imu:c1")]


def test_locked_without_health_uses_excitation() -> None:
    cur = topo(
        imus={"b1": "j1", "b2": "j1"},
        joints={"j3": "j1"},
        undetermined=("j2",),
        excitation={**EXC, "j2": 0.0},
    )
    assert kinds(diff_bodies(BASE, cur)) == [("joint_locked", "joint:j2")]


def test_ambiguous_estimate_gives_only_signal_findings() -> None:
    # several trees fit: the estimate parks everything on the base; only the dead IMU is reported
    cur = topo(
        joints={j: None for j in JOINTS}, imus={i: None for i in IMUS}, unique=False, candidates=(BASE,)
    )
    d = diff_bodies(BASE, cur, health(imus={"e1": "zero"}))
    assert kinds(d) == [("imu_dead", "imu:e1")]
    d = diff_bodies(BASE, cur, health(joints={"j3": "frozen_encoder"}, excitation={"j3": 0.0}))
    assert kinds(d) == [("encoder_fault", "joint:j3")]


def test_a_joint_the_window_did_not_move_is_never_no_change():
    """Unique, matching the baseline everywhere it decides, but one joint unplaced: undetermined."""
    base = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"})
    still = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"}, undetermined=("j2",))
    d = diff_bodies(base, still)
    assert d.changed is None
    assert d.to_json()["changed"] is None
    assert d.reasons == (
        "the window does not move joint j2 enough to place it; to decide, move each on its own with the "
        "others still",
    )
    assert diff_bodies(base, base).changed is False


def test_a_baseline_that_did_not_place_a_part_backs_no_placement_finding():
    """A joint the baseline window did not move hangs on the base as a placeholder there, its link's IMUs
    on its parent link: the current window placing them is no damage, and no "no change" either."""
    base = Topology({"j1": None, "j2": None}, {"i1": "j1", "i2": "j1"}, undetermined=("j2",))
    moved = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"})
    d = diff_bodies(base, moved)
    assert d.findings == () and d.changed is None
    assert d.reasons == (
        "baseline: the window does not move joint j2 enough to place it; to decide, move each on its own "
        "with the others still",
    )


def test_an_ambiguous_baseline_backs_no_placement_finding():
    a = Topology({"j1": None, "j2": "j1"}, {"i1": "j1", "i2": "j2"})
    b = Topology({"j1": "j2", "j2": None}, {"i1": "j1", "i2": "j2"})
    amb = Topology(a.joint_parent, a.imu_joint, unique=False, candidates=(b,))
    d = diff_bodies(amb, b)
    assert d.findings == () and d.changed is None
    assert d.reasons[0].startswith("baseline: 2 trees fit the data; they differ in joint j1")
    assert (
        d.reasons[-1]
        == "baseline: to decide, move each of these joints on its own with the others still: j1, j2"
    )
