"""Two methods, one verdict, in the robot status: per part what the newest fast topology and the
newest sensor-network topology say together, on real stores with stored topologies (no training).

The last third checks the worker's baseline and alert path against the same rule (a baseline or an
alert never rests on one method's decided answer that the other contradicts): what holds is tested
as it is.
"""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from bodyschema.diff import diff_bodies
from bodyschema.health import JointHealth, SignalHealth
from bodyschema.topology import Topology
from service.alert_path import baseline_verdict
from service.alerts import Evidence
from service.api import create_app
from service.frames import FrameBatch
from service.monitor.baseline import BaselineAdoption
from service.monitor.confirmation import NetworkAsks, confirm
from service.monitor.state import RobotState
from service.settings import Settings
from service.status import methods_verdict, robot_status, robot_statuses
from service.store import Store, TopologyRecord

SETTINGS = Settings(database_url="sqlite://", worker_interval_seconds=1.0, api_cache_seconds=0.0)
JOINTS = ("j1", "j2", "j3")
IMUS = ("imu0", "imu1", "imu2")
# A serial chain j1 → j2 → j3, one IMU per link.
BODY = Topology(
    {"j1": None, "j2": "j1", "j3": "j2"}, {"imu0": "j1", "imu1": "j2", "imu2": "j3"}, method="fast"
)
# The networks' other body: j3 hangs under j1. Only joint:j3 differs.
OTHER = Topology(
    {"j1": None, "j2": "j1", "j3": "j1"},
    {"imu0": "j1", "imu1": "j2", "imu2": "j3"},
    method="network",
    confidence={"joint:j3": 0.8},
)
# imu2 moved from j3's link onto j2's.
MOVED = Topology(
    {"j1": None, "j2": "j1", "j3": "j2"}, {"imu0": "j1", "imu1": "j2", "imu2": "j2"}, method="fast"
)
PARTS = ["joint:j1", "joint:j2", "joint:j3", "imu:imu0", "imu:imu1", "imu:imu2"]


def net_of(topo: Topology, conf: dict[str, float] | None = None) -> Topology:
    """``topo`` as the sensor networks would store it (method ``network``): confidence 0.9 on every
    part but those ``conf`` names."""
    conf = dict.fromkeys(PARTS, 0.9) | (conf or {})
    return Topology(dict(topo.joint_parent), dict(topo.imu_joint), method="network", confidence=conf)


# The networks' answer is not unique, but both trees they list hang j3 under j1 (they differ on imu1):
# they decide joint:j3, against the fast method.
AMBIGUOUS_OTHER = Topology(
    dict(OTHER.joint_parent),
    dict(OTHER.imu_joint),
    unique=False,
    method="network",
    candidates=(Topology(dict(OTHER.joint_parent), {**OTHER.imu_joint, "imu1": "j1"}),),
)


def frames(store: Store, robot: str = "arm") -> None:
    n = 20
    store.write(
        FrameBatch(
            robot,
            np.arange(n) * 0.01,
            JOINTS,
            np.zeros((n, 3)),
            IMUS,
            np.full((n, 3, 3), 9.81),
            np.zeros((n, 3, 3)),
        )
    )


def status(c: TestClient, robot: str = "arm", **params: str) -> dict:
    r = c.get(f"/api/v1/robots/{robot}/status", params=params)
    assert r.status_code == 200, r.text
    body = r.json()
    if not params:  # the robot list's answer is the same, read for the fleet at once
        assert c.get(f"/api/v1/robots/{robot}").json()["status"] == body
    return body


def by_part(body: dict) -> dict[str, dict]:
    return {p["part"]: p for p in body["parts"]}


@pytest.fixture
def client(store: Store) -> TestClient:
    frames(store)
    return TestClient(create_app(store, settings=SETTINGS))


# ----------------------------------------------------------------------------------------- status


def test_without_the_networks_every_part_rests_on_the_fast_method_unconfirmed(
    store: Store, client: TestClient
) -> None:
    store.set_baseline("arm", BODY, "auto", wall_time=100.0, window_end_t=10.0)
    fid = store.save_topology("arm", BODY, 101.0, 11.0)
    body = status(client)
    assert body["status"] == "healthy"  # the networks being late does not make the robot undetermined
    assert [p["part"] for p in body["parts"]] == PARTS
    assert {p["verdict"] for p in body["parts"]} == {"unconfirmed"}
    assert by_part(body)["joint:j3"] == {
        "part": "joint:j3",
        "verdict": "unconfirmed",
        "fast": "j2",
        "network": None,
        "fast_decided": True,
        "network_decided": False,
        "contradicted": False,
        "confidence": 1.0,
        "move": [],
    }
    m = body["methods"]
    assert (m["basis"], m["fast_topology_id"], m["network_topology_id"]) == ("fast", fid, None)
    assert (m["agreed"], m["unconfirmed"], m["undetermined"], m["contradicted"]) == (0, 6, 0, 0)
    assert m["note"] == (
        "the verdict rests on the fast method alone and is unconfirmed: "
        "the sensor networks have not answered yet"
    )


def test_both_methods_alike_is_agreed_on_every_part(store: Store, client: TestClient) -> None:
    store.set_baseline("arm", BODY, "auto", wall_time=100.0, window_end_t=10.0)
    store.save_topology("arm", BODY, 101.0, 11.0)
    nid = store.save_topology("arm", net_of(BODY, {"joint:j3": 0.7}), 102.0, 11.0)
    body = status(client)
    assert body["status"] == "healthy"
    assert {p["verdict"] for p in body["parts"]} == {"agreed"}
    # agreed: the larger of the two confidences (the fast method's 1.0 beside the networks' 0.7)
    assert by_part(body)["joint:j3"]["confidence"] == 1.0
    assert by_part(body)["joint:j3"]["network"] == "j2"
    m = body["methods"]
    assert (m["basis"], m["network_topology_id"], m["network_window_end_t"]) == ("fast+network", nid, 11.0)
    assert (m["agreed"], m["unconfirmed"], m["undetermined"], m["contradicted"]) == (6, 0, 0, 0)


def test_a_part_the_networks_contradict_is_undetermined_with_both_answers_and_what_to_move(
    store: Store, client: TestClient
) -> None:
    store.set_baseline("arm", BODY, "auto", wall_time=100.0, window_end_t=10.0)
    store.save_topology("arm", BODY, 101.0, 11.0)
    store.save_topology("arm", net_of(OTHER), 102.0, 12.0)
    body = status(client)
    assert body["status"] == "undetermined"  # the fast method alone matches the baseline: not enough
    assert by_part(body)["joint:j3"] == {
        "part": "joint:j3",
        "verdict": "undetermined",
        "fast": "j2",
        "network": "j1",
        "fast_decided": True,
        "network_decided": True,
        "contradicted": True,
        "confidence": 0.5,
        "move": ["j2", "j3"],
    }
    assert {p["part"] for p in body["parts"] if p["verdict"] == "agreed"} == set(PARTS) - {"joint:j3"}
    m = body["methods"]
    assert (m["agreed"], m["unconfirmed"], m["undetermined"], m["contradicted"]) == (5, 0, 1, 1)
    assert body["decide_by"] == ["j2", "j3"]
    assert body["reasons"] == [
        "the fast method and the sensor networks contradict each other on joint:j3 (fast: parent j2; "
        "networks: parent j1): to decide, move each of these joints on its own with the others still: "
        "j2, j3"
    ]


def test_a_part_the_networks_leave_open_is_undetermined_but_the_robot_stays_healthy(
    store: Store, client: TestClient
) -> None:
    store.set_baseline("arm", BODY, "auto", wall_time=100.0, window_end_t=10.0)
    store.save_topology("arm", BODY, 101.0, 11.0)
    store.save_topology("arm", net_of(OTHER, {"joint:j3": 0.3}), 102.0, 12.0)
    body = status(client)
    assert body["status"] == "healthy"  # undecided is not contradicted: the fast answer stands
    p = by_part(body)["joint:j3"]
    assert (p["verdict"], p["contradicted"], p["network_decided"], p["confidence"]) == (
        "undetermined",
        False,
        False,
        0.3,
    )
    assert p["move"] == ["j2", "j3"]
    assert body["methods"]["undetermined"] == 1 and body["methods"]["contradicted"] == 0


def test_a_network_answer_older_than_the_baseline_of_another_body_is_stale(
    store: Store, client: TestClient
) -> None:
    store.save_topology("arm", net_of(OTHER), 90.0, 5.0)  # learned of the body before the repair
    store.set_baseline("arm", BODY, "operator", wall_time=100.0)
    store.save_topology("arm", BODY, 101.0, 11.0)
    body = status(client)
    assert body["status"] == "healthy"
    m = body["methods"]
    assert (m["basis"], m["network_stale"], m["unconfirmed"]) == ("fast", True, 6)
    assert "stale" in m["note"] and m["note"].startswith("the verdict rests on the fast method alone")
    assert {p["network"] for p in body["parts"]} == {None}


def test_a_network_answer_older_than_a_baseline_of_its_own_body_is_not_stale(store: Store) -> None:
    frames(store)
    # the worker adopts the networks' answer as the baseline and stamps it with the later fast window
    nid = store.save_topology("arm", net_of(BODY), 100.0, 8.0)
    store.set_baseline("arm", BODY, "auto", wall_time=101.0, window_end_t=12.0)
    store.save_topology("arm", BODY, 102.0, 13.0)
    st = robot_status(store, "arm")
    assert (st.methods.basis, st.methods.network_id, st.methods.network_stale) == ("fast+network", nid, False)
    assert st.methods.counts["agreed"] == 6


def test_a_network_answer_of_other_parts_leaves_the_fast_method_alone(store: Store) -> None:
    frames(store)
    store.save_topology("arm", BODY, 101.0, 11.0)
    fewer = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j2"}, method="network")
    store.save_topology("arm", fewer, 102.0, 12.0)
    m = robot_status(store, "arm").methods
    assert m.basis == "fast"
    assert m.note.endswith("names other joints or IMUs")


def test_the_parts_are_judged_on_the_fast_topology_whatever_method_is_asked(
    store: Store, client: TestClient
) -> None:
    store.set_baseline("arm", BODY, "auto", wall_time=100.0, window_end_t=10.0)
    fid = store.save_topology("arm", BODY, 101.0, 11.0)
    nid = store.save_topology("arm", net_of(OTHER), 102.0, 12.0)
    body = status(client, method="network")
    assert body["topology_id"] == nid
    assert (body["methods"]["fast_topology_id"], body["methods"]["network_topology_id"]) == (fid, nid)
    assert body["methods"]["contradicted"] == 1


def test_nothing_learned_judges_no_part(store: Store, client: TestClient) -> None:
    body = status(client)
    assert body["parts"] == []
    assert body["methods"]["basis"] == ""
    assert body["methods"]["note"] == "the fast method has learned nothing yet: no part is judged"


def test_a_fleet_read_at_once_judges_the_parts_as_one_robot_read_alone(store: Store) -> None:
    for r in ("a", "b"):
        frames(store, r)
        store.set_baseline(r, BODY, "auto", wall_time=100.0, window_end_t=10.0)
        store.save_topology(r, BODY, 101.0, 11.0)
    store.save_topology("b", net_of(OTHER), 102.0, 12.0)
    fleet = robot_statuses(store, ["a", "b"])
    for r in ("a", "b"):
        assert fleet[r].methods == robot_status(store, r).methods
    assert (fleet["a"].status, fleet["b"].status) == ("healthy", "undetermined")


def test_the_new_fields_are_documented_in_the_openapi_document(client: TestClient) -> None:
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    status_props = schemas["StatusOut"]["properties"]
    assert status_props["parts"]["description"].startswith("every joint and IMU")
    assert status_props["methods"]["description"].startswith("what the parts' verdicts rest on")
    for name in ("PartOut", "MethodsOut"):
        undocumented = [k for k, v in schemas[name]["properties"].items() if not v.get("description")]
        assert undocumented == [], name
    assert schemas["PartOut"]["properties"]["verdict"]["enum"] == ["agreed", "unconfirmed", "undetermined"]


# ---------------------------------------------------------- the baseline and alert path, checked


def record(topo: Topology, window_end: float, tid: int = 2, method: str = "network") -> TopologyRecord:
    return TopologyRecord(tid, "arm", 100.0 + window_end, window_end, method, topo)


def test_a_fast_baseline_the_networks_contradict_afterwards_is_flagged_twice() -> None:
    base = TopologyRecord(1, "arm", 110.0, 10.0, "fast", BODY, "fast-unconfirmed")
    assert baseline_verdict(base, record(net_of(OTHER), 20.0))[0] == "contradicted"
    m = methods_verdict(record(BODY, 21.0, 3, "fast"), record(net_of(OTHER), 20.0), base)
    assert [p.part for p in m.contradicted] == ["joint:j3"]


def test_a_fast_baseline_the_ambiguous_networks_contradict_on_a_part_is_not_healthy(store: Store) -> None:
    """Every tree the ambiguous network topology lists hangs j3 elsewhere: :func:`baseline_verdict`
    calls the baseline contradicted on that part, and the parts verdict sees the same."""
    frames(store)
    store.set_baseline("arm", BODY, "fast-unconfirmed", wall_time=100.0, window_end_t=10.0)
    store.save_topology("arm", BODY, 101.0, 11.0)
    store.save_topology("arm", AMBIGUOUS_OTHER, 102.0, 12.0)
    st = robot_status(store, "arm")
    assert st.baseline_networks == "contradicted"
    assert st.status == "undetermined"
    assert [p.part for p in st.methods.contradicted] == ["joint:j3"]


def adoption(store: Store, clock: list[float]) -> tuple[BaselineAdoption, RobotState, list[str]]:
    settings = SETTINGS.model_copy(
        update={
            "network_interval_cycles": 1,
            "baseline_repeat_k": 2,
            "baseline_unconfirmed_cycles": 3,
            "baseline_unconfirmed_seconds": 0.0,
        }
    )
    asked: list[str] = []
    asks = NetworkAsks(settings, lambda: clock[0], asked.append)
    return BaselineAdoption(store, settings, lambda: clock[0], asks), RobotState(), asked


HEALTHY = SignalHealth(joints={j: JointHealth(j, "ok", 1.0) for j in JOINTS})


def offer_cycles(store: Store, net: Topology | None, cycles: int = 5) -> list[bool]:
    """What each cycle's offer returned: the fast method learns BODY each cycle (windows ending 10,
    20, ...) until a baseline is adopted or ``cycles`` pass; the networks' ``net`` is stored from the
    window ending at 15 (after the streak began)."""
    frames(store)
    if net is not None:
        store.save_topology("arm", net, 50.0, 15.0)
    clock = [100.0]
    adopt, state, _ = adoption(store, clock)
    out = []
    for k in range(cycles):
        clock[0] += 10.0
        out.append(adopt.offer("arm", state, BODY, HEALTHY, 10.0 * (k + 1)))
        if out[-1]:
            break
    return out


def test_a_baseline_waits_while_the_networks_answer_another_body(store: Store) -> None:
    assert offer_cycles(store, net_of(OTHER)) == [False] * 5
    assert store.baseline("arm") is None


def test_a_baseline_the_networks_share_is_theirs(store: Store) -> None:
    assert offer_cycles(store, net_of(BODY)) == [False, True]
    base = store.baseline("arm")
    assert base is not None and base.source == "auto" and base.topology.same_structure(BODY)


def test_without_a_network_answer_the_fast_body_is_adopted_marked_unconfirmed(store: Store) -> None:
    assert offer_cycles(store, None) == [False, False, True]
    base = store.baseline("arm")
    assert base is not None and base.source == "fast-unconfirmed"


def test_a_baseline_waits_while_the_ambiguous_networks_decide_a_part_against_it(store: Store) -> None:
    assert offer_cycles(store, AMBIGUOUS_OTHER) == [False] * 5


def confirmed(fast: Topology, net: Topology | None, net_end: float = 20.0) -> tuple[Evidence, list[str]]:
    """The sensor networks' word (``net``, window ending at ``net_end``) on the fast finding of
    ``fast`` against BODY, first seen in the window ending at 10."""
    asked: list[str] = []
    asks = NetworkAsks(SETTINGS.model_copy(update={"network_interval_cycles": 1}), lambda: 0.0, asked.append)
    diff = diff_bodies(BODY, fast)
    rec = None if net is None else record(net, net_end)
    _, ev = confirm("arm", RobotState(), diff, BODY, 10.0, rec, Evidence(now=1.0), asks)
    return ev, asked


def test_a_fast_finding_the_networks_share_is_confirmed() -> None:
    ev, _ = confirmed(MOVED, net_of(MOVED))
    assert ev.confirmed == {("imu_moved", "imu:imu2")} and not ev.withdrawn and not ev.waiting


def test_a_fast_finding_the_networks_see_no_change_of_is_withdrawn() -> None:
    ev, _ = confirmed(MOVED, net_of(BODY))
    assert list(ev.withdrawn) == [("imu_moved", "imu:imu2")] and not ev.confirmed


def test_a_fast_finding_waits_for_a_network_window_after_it() -> None:
    ev, asked = confirmed(MOVED, net_of(BODY), net_end=5.0)
    assert ev.waiting == {("imu_moved", "imu:imu2")} and not ev.withdrawn and asked == ["arm"]


def test_a_fast_finding_the_networks_place_elsewhere_is_not_confirmed() -> None:
    elsewhere = Topology(dict(BODY.joint_parent), {**BODY.imu_joint, "imu2": "j1"})
    ev, _ = confirmed(MOVED, net_of(elsewhere))
    assert not ev.confirmed


def test_a_fast_finding_the_ambiguous_networks_decide_against_is_withdrawn() -> None:
    keep = Topology(
        dict(BODY.joint_parent),
        dict(BODY.imu_joint),
        unique=False,
        method="network",
        candidates=(Topology({**BODY.joint_parent, "j3": "j1"}, dict(BODY.imu_joint)),),
    )
    ev, _ = confirmed(MOVED, keep)
    assert list(ev.withdrawn) == [("imu_moved", "imu:imu2")]
