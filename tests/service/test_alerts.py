"""Alert hysteresis: raise after M, resolve after M, never flap."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.findings import Finding
from service.alerts import AlertTracker, Transition

DEAD = Finding("imu_dead", imu="imu3")
LOCK = Finding("joint_locked", joint="j2")


def raised(transitions: list[Transition]) -> list[Transition]:
    """The transitions that raise or resolve (a first sighting is also reported, as pending)."""
    return [t for t in transitions if t.state != "pending"]


@pytest.mark.parametrize("m", [1, 2, 3, 5])
def test_raise_after_m_resolve_after_m(m: int) -> None:
    tr = AlertTracker(m=m)
    for cycle in range(1, m):
        out = tr.update("r", [DEAD])
        assert [t.state for t in out] == (["pending"] if cycle == 1 else []), cycle
        assert tr.pending("r") == [("r", "imu_dead", "imu:imu3")]
    raised = tr.update("r", [DEAD])
    assert [(t.state, t.kind, t.part) for t in raised] == [("active", "imu_dead", "imu:imu3")]
    assert tr.update("r", [DEAD]) == []  # raised once only
    for _ in range(m - 1):
        assert tr.update("r", []) == []
        assert tr.active("r") == [("r", "imu_dead", "imu:imu3")]
    resolved = tr.update("r", [])
    assert [(t.state, t.part) for t in resolved] == [("resolved", "imu:imu3")]
    assert tr.active() == [] and tr.pending() == []


def test_alternating_input_never_raises() -> None:
    tr = AlertTracker(m=2)
    out = []
    for k in range(50):
        out += tr.update("r", [DEAD] if k % 2 == 0 else [])
    assert [t.state for t in out] == ["pending"]  # seen once, then neither raised nor cleared


def test_alternating_input_never_clears_an_active_alert() -> None:
    tr = AlertTracker(m=2)
    assert [t.state for t in tr.update("r", [LOCK])] == ["pending"]
    assert len(tr.update("r", [LOCK])) == 1
    out = []
    for k in range(50):
        out += tr.update("r", [] if k % 2 == 0 else [LOCK])
    assert out == []
    assert tr.active("r") == [("r", "joint_locked", "joint:j2")]


def test_random_input_transitions_alternate(rng: np.random.Generator) -> None:
    """Whatever the input, per key the transitions go active, resolved, active, ... and each raise is
    preceded by m consecutive sightings."""
    m = int(rng.integers(1, 4))
    tr = AlertTracker(m=m)
    history: list[bool] = []
    states: list[str] = []
    for _ in range(300):
        present = bool(rng.random() < 0.6)
        history.append(present)
        for t in raised(tr.update("r", [DEAD] if present else [])):
            if t.note.startswith("not seen") and t.state == "resolved" and not states[-1:] == ["active"]:
                continue  # a pending alert that never rose, gone M cycles
            states.append(t.state)
            window = history[-m:]
            assert all(window) if t.state == "active" else not any(window)
    assert states == ["active", "resolved"] * (len(states) // 2) + (["active"] if len(states) % 2 else [])


def test_robots_are_independent() -> None:
    tr = AlertTracker(m=2)
    assert [t.state for t in tr.update("a", [DEAD])] == ["pending"]
    tr.update("b", [])
    assert tr.pending("a") == [("a", "imu_dead", "imu:imu3")]
    assert [t.robot for t in tr.update("a", [DEAD])] == ["a"]
    assert tr.update("b", []) == []
    assert tr.active("b") == []


def test_insufficient_excitation_never_alerts() -> None:
    tr = AlertTracker(m=1)
    assert tr.update("r", [Finding("insufficient_excitation", joint="j1")]) == []


def test_restore_then_resolve() -> None:
    tr = AlertTracker(m=2)
    tr.restore("r", [LOCK])
    assert tr.update("r", [LOCK]) == []
    tr.update("r", [])
    assert [t.state for t in tr.update("r", [])] == ["resolved"]


def test_forget_and_bad_m() -> None:
    tr = AlertTracker(m=1)
    tr.update("r", [DEAD])
    tr.forget("r")
    assert tr.active() == []
    with pytest.raises(ValueError, match="m must be"):
        AlertTracker(m=0)


def test_held_kinds_are_neither_seen_nor_gone() -> None:
    moved = Finding("imu_moved", imu="imu1", from_="j1", to="j2")
    tr = AlertTracker(m=2)
    assert [t.state for t in tr.update("r", [moved])] == ["pending"]
    assert tr.update("r", [], hold=["imu_moved"]) == []  # an ambiguous cycle: no information
    assert [t.state for t in tr.update("r", [moved])] == ["active"]
    for _ in range(5):
        assert tr.update("r", [], hold=["imu_moved"]) == []
    assert tr.active("r") == [("r", "imu_moved", "imu:imu1")]
    tr.update("r", [])
    assert [t.state for t in tr.update("r", [])] == ["resolved"]
