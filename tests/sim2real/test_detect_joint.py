"""The detection bench scores a hidden effect named jointly by the joint value: the untouched trial's
joint value with the hidden changes carried over through the reported maps."""

from __future__ import annotations

import numpy as np

from bench.sim2real_detect import _joint_check, _members, _own_joint
from bodyschema.discrepancy.report import Cause, DiscrepancyReport, JointCause

G0 = np.array([0.0, 0.0, -9.81])
#: a level sensor: a gravity change dg reads as an accelerometer change of -dg
MAPS = {"gravity": (-np.eye(3)).tolist()}


def _joint(value: list[float], half: float = 0.003, named: tuple[str, ...] = ("acc_bias",)) -> JointCause:
    return JointCause(
        ("acc_bias", "gravity"), named, {"vector": value}, {}, [[v - half, v + half] for v in value],
        0.99, 0.42, MAPS, "rotate the sensor",
    )  # fmt: skip


def _report(*, joint=(), causes=(), params=None) -> DiscrepancyReport:
    return DiscrepancyReport({}, list(causes), {}, {}, params=dict(params or {}), joint=list(joint))


def test_a_hidden_bias_is_scored_on_the_joint_value() -> None:
    null = _report(joint=[_joint([0.02, 0.0, 0.01])], params={"acc_bias": {"vector": [0.02, 0.0, 0.01]}})
    hidden = {"acc_bias": {"vector": [0.3, -0.1, 0.0]}}
    good = _joint_check(_joint([0.321, -0.1, 0.012]), null, hidden, G0)
    bad = _joint_check(_joint([0.30, -0.1, 0.0]), null, hidden, G0)  # the trial's own share lost
    assert good["named"] and good["within"] and good["joint"] == "acc_bias or gravity"
    assert bad["named"] and not bad["within"] and bad["z"] > 3


def test_a_hidden_gravity_tilt_is_carried_over_through_the_map() -> None:
    null = _report(joint=[_joint([0.02, 0.0, 0.01])], params={"acc_bias": {"vector": [0.02, 0.0, 0.01]}})
    g = np.add(G0, [0.1, -0.05, 0.0])
    rep = _joint([0.02 - 0.1, 0.05, 0.01], named=("gravity",))
    assert _joint_check(rep, null, {"gravity": {"vector": g.tolist()}}, G0)["within"]


def test_an_untouched_trial_that_named_a_member_alone_is_carried_over() -> None:
    g = np.add(G0, [0.05, 0.0, 0.0])
    cause = Cause("gravity", {"vector": g.tolist()}, {}, 0.1, 1e-9, "", 0.1,
                  interval=[[x - 0.002, x + 0.002] for x in g])  # fmt: skip
    null = DiscrepancyReport({}, [cause], {}, {}, evidence=[
        {"effect": "acc_bias", "channel": "acc", "estimate": [0.01, 0.0, 0.0], "stderr": [0.001] * 3,
         "p_value": 0.5},
        {"effect": "gravity", "channel": "acc", "estimate": [0.05, 0.0, 0.0], "stderr": [0.001] * 3,
         "p_value": 1e-9},
    ])  # fmt: skip
    value, se = _own_joint(null, _joint([0.0, 0.0, 0.0]), G0)
    assert np.allclose(value, [0.01 - 0.05, 0.0, 0.0]) and np.all(se > 0.001)


def test_a_joint_name_stands_for_its_members() -> None:
    rep = _report(joint=[_joint([0.0, 0.0, 0.0])], causes=[Cause("time_offset", {}, {}, 0.1, 1e-9, "", 0.1)])
    assert _members(rep) == {"time_offset": {"time_offset"}, "acc_bias or gravity": {"acc_bias", "gravity"}}
    assert rep.stated == {"time_offset", "acc_bias", "gravity"}
