"""``bodyhealth bench drift``, its service part: the worker's real cycle on a healthy fleet, the fleet
split over processes, raises nothing, keeps every robot's geometry and reports the networks' retrains;
the table says so. The networks are on with an interval past the run, so each robot trains them once,
for its baseline: the schedule is the worker tests' (tests/service/test_worker.py), and two scheduled
retrains more would nearly double this test's CPU time."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import drift as bench
from tests.bench.args import bench_args

pytestmark = pytest.mark.slow


def test_the_service_part_splits_the_fleet_over_processes(tmp_path: Path) -> None:
    # each robot in a process of its own: the same cycles for each, the counts added, every robot's
    # baseline and geometry kept; a robot's data do not depend on the others (the farm's seeds)
    args = ["--robots", "ur5e", "--parts", "service", "--fleet", "ur5e,ur5e", "--hours", "0.03"]
    md = bench.run(bench_args(bench, *args, "--networks", "100", "--jobs", "2", "--out", str(tmp_path)))
    d = json.loads((tmp_path / "drift.json").read_text())
    assert d["catalog"] == [] and d["pooled"] is None
    s = d["service"]
    assert s["processes"] == 2 and s["fleet"] == {"ur5e-0": "ur5e", "ur5e-1": "ur5e"}
    assert s["cycles"] == 22 and s["baseline_cycle"] == {"ur5e-0": 8, "ur5e-1": 8}
    assert s["geometry_kept"] == {"ur5e-0": True, "ur5e-1": True}
    # the networks on (the suite turns them off): a baseline waits for their agreement, one retrain
    # per robot, and none is due again within the run's 22 cycles
    assert s["network_interval_cycles"] == 100 and s["network_retrains"] == 2
    assert s["geometry_comparisons"] >= 2 and s["alerts_raised"] == []
    assert s["drift_findings"] == 0 and s["drift_finding_details"] == []
    # the service's pool sizes; 22 cycles are far from filling the baseline's pool of 80
    assert s["pool_sizes"] == [80, 40] and s["slide_comparisons"] == 0
    text = md.read_text()
    assert "CPU s (the sum of 2 processes, the fleet's robots split over them)" in text
    assert "0 alerts raised" in text and "networks every 100 cycles: 2 network retrains" in text
    assert f"{s['geometry_comparisons']} geometry comparisons (0 of them with the lever arms)" in text
    assert "slides judged on pools of 80 and 40 estimates" in text
