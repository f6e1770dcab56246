"""``bench shapes``: which joints hardly moved where the estimator looks, and how a cell reads."""

from __future__ import annotations

import numpy as np

from bench import shapes


def test_a_joint_that_settles_into_a_jam_at_the_start_hardly_moved():
    t = np.arange(6000) / 100.0
    settles = np.where(t < 0.3, 5.0 * np.sin(40 * t), 0.004 * np.sin(0.7 * t))  # 0.3 s, then jammed
    slow = 0.06 * np.sqrt(2) * np.sin(0.9 * t)  # 0.06 rad/s RMS: moved
    chatter = 0.02 * np.sin(2 * np.pi * 30 * t)  # above the 10 Hz band only
    qd = np.stack([settles, slow, chatter], axis=1)
    assert float(np.sqrt(np.mean(settles**2))) > 0.2  # over the whole recording it looks lively
    assert shapes.still_joints(qd, ["a", "b", "c"], 100.0, dlpf=False) == ["a", "c"]
    assert shapes.still_joints(qd, ["a", "b", "c"], 100.0, dlpf=True) == ["a", "c"]


def test_cells_name_the_joints_to_move_and_those_this_motion_cannot_decide():
    row = {"verdict": "undetermined", "named": ["j04", "j06", "j11"], "still_joints": ["j06", "j11"]}
    assert shapes._cell(row) == "undetermined (move j04; j06, j11 undeterminable by this motion)"
    assert shapes._cell({**row, "named": ["j06"]}) == "undetermined (j06 undeterminable by this motion)"
    assert shapes._cell({**row, "named": ["j04"], "still_joints": []}) == "undetermined (move j04)"
    assert shapes._cell({"verdict": "wrong", "named": [], "still_joints": []}) == "**wrong**"


def test_the_summary_counts_exact_answers_where_every_joint_moved():
    rows = [
        {"shape": "multi-rate", "verdict": v, "named": n, "still_joints": s, "cpu_s": 0.1}
        for v, n, s in (("exact", [], []), ("undetermined", ["j1"], ["j1"]), ("exact", [], ["j2"]))
    ]
    s = shapes._summary(rows)["multi-rate"]
    assert (s["exact"], s["undetermined"], s["wrong"]) == (2, 1, 0)
    assert (s["robots_all_moved"], s["exact_all_moved"]) == (1, 1)
