"""``bodyhealth bench drift``, its pooled part: slides judged on lever arms pooled over windows, as the
worker judges them, on pools of 12 and 6 estimates (the part takes the service's pool sizes; the
defaults, 80 and 40, would take some 120 windows): a healthy robot gives no finding, each slid IMU
is the one the part says it picks, and the wrist IMU's slide is found."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from bench import drift as bench
from tests.bench.args import bench_args

pytestmark = pytest.mark.slow

N_BASE, N_RECENT = 12, 6


def test_pooled_part_judges_slides_on_the_pools_of_the_settings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("BODYHEALTH_KINEMATICS_POOL_BASE", str(N_BASE))
    monkeypatch.setenv("BODYHEALTH_KINEMATICS_POOL_RECENT", str(N_RECENT))
    argv = ["--robots", "ur5e", "--nominal", "2", "--pool-slides-mm", "20", "--pool-after", "2"]
    md = bench.run(bench_args(bench, *argv, "--parts", "pooled", "--out", str(tmp_path)))
    d = json.loads((tmp_path / "drift.json").read_text())
    assert d["catalog"] == [] and d["service"] is None
    p = d["pooled"]
    assert (p["robot"], p["n_base"], p["n_recent"], p["nominal_windows"]) == ("ur5e", N_BASE, N_RECENT, 8)
    assert p["nominal_findings"] == [[]] * 8 and p["windows_after"] == 2
    # the IMU with the longest lever arm (an upper-arm one, about 0.2 m) and the wrist's last IMU
    assert [g["imu"] for g in p["slides"]][1] == "imu11" and p["slides"][0]["lever_arm_mm"] > 150
    assert [g["mm"] for g in p["slides"]] == [20.0, 20.0]
    assert all(len(g["scatter_mm"]) == 3 and g["other_findings"] == 0 for g in p["slides"])
    # the wrist's IMU, a few cm from its axis: its 20 mm slide is found once 2 estimates show it
    wrist = p["slides"][1]
    assert wrist["windows_to_finding"] == 2, wrist
    moved = re.match(r"lever arm moved ([0-9.]+) mm, the mean of the last 2 estimates", wrist["finding"])
    assert moved and 15.0 < float(moved.group(1)) < 25.0, wrist["finding"]
    text = md.read_text()
    assert (
        f"Pooled slides (ur5e): the lever arms of the first {N_BASE} windows against the mean of the "
        f"newest k, for every k up to {N_RECENT}" in text
    )
    assert "Healthy: 0 findings in 8 windows judged. Each slide judged for 2 windows after it:" in text
