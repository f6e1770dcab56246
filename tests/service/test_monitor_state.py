"""What the worker forgets of a robot on each event (service.monitor.state), stated once."""

from __future__ import annotations

import dataclasses

import pytest

from bodyschema.topology import Topology
from service.monitor.state import FORGETS, RobotState

TREE = Topology({"j1": None}, {"i1": "j1"})


def _lived() -> RobotState:
    """A state in which every field differs from a new one's."""
    st = RobotState(
        fingerprints=object(),  # type: ignore[arg-type]
        requests={"network"},
        findings=frozenset({("imu_moved", "imu:i1")}),
        first_seen={("imu_moved", "imu:i1"): 10.0},
        network_asked=5.0,
        onset={"i1": 10.0},
        activity=(12.0, 100.0),
        epoch=3,
        lag=0.13,
        baseline_id=7,
        baseline_known=True,
        rejudge=False,
        waits_written={"waits": [], "queue": []},
    )
    st.streak.add(TREE, 9.0, k=3)
    st.streak.since, st.streak.wall = 9.0, 99.0
    return st


def _changed(before: RobotState, after: RobotState) -> set[str]:
    return {
        f.name for f in dataclasses.fields(RobotState) if getattr(before, f.name) != getattr(after, f.name)
    }


@pytest.mark.parametrize(
    ("reason", "changed"),
    [
        ("approval", {"fingerprints"}),
        ("adopted", {"fingerprints", "streak"}),
        ("baseline", {"fingerprints", "onset", "first_seen", "findings"}),
        ("epoch", {"fingerprints", "onset", "first_seen", "lag", "rejudge"}),
    ],
)
def test_each_event_forgets_what_it_says_and_keeps_the_rest(reason: str, changed: set[str]) -> None:
    before, after = _lived(), _lived()
    after.reset(reason)
    assert _changed(before, after) == changed
    if reason == "epoch":  # the lag is searched from zero again, not read back from the store
        assert (after.lag, after.rejudge) == (0.0, True)
    if "streak" in changed:
        assert (after.streak.n, list(after.streak.topologies), after.streak.start) == (0, [], None)


def test_a_restart_forgets_everything_and_judges_the_alerts_again() -> None:
    st = _lived()
    st.reset("restart")
    assert st == dataclasses.replace(RobotState(), rejudge=True)
    assert set(FORGETS) == {"approval", "adopted", "baseline", "epoch", "restart"}


def test_a_streak_keeps_k_topologies_and_counts_every_cycle() -> None:
    st = RobotState()
    for end in (1.0, 2.0, 3.0, 4.0):
        st.streak.add(TREE, end, k=3)
    assert (len(st.streak.topologies), st.streak.n, st.streak.start) == (3, 4, 1.0)
