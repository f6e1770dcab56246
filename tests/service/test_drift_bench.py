"""``bodyhealth bench drift``: a short run finds each 2° damage first on its part, raises nothing on a
healthy robot, and writes its table, JSON and plot."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from bench import drift as bench

pytestmark = pytest.mark.slow


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    return p.parse_args(list(argv))


def test_short_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the pooled part and the service take the service's pool sizes: half the defaults keep it short
    monkeypatch.setenv("BODYHEALTH_KINEMATICS_POOL_BASE", "40")
    monkeypatch.setenv("BODYHEALTH_KINEMATICS_POOL_RECENT", "20")
    md = bench.run(
        _args(
            "--robots",
            "ur5e",
            "--nominal",
            "2",
            "--slide-mm",
            "5",
            "--pool-slides-mm",
            "20",
            "--pool-after",
            "2",
            "--fleet",
            "ur5e",
            "--hours",
            "0.05",
            "--networks",
            "12",
            "--out",
            str(tmp_path),
        )
    )
    d = json.loads((tmp_path / "drift.json").read_text())
    (r,) = d["catalog"]
    assert r["robot"] == "ur5e" and r["axis_converged"] == r["imus_on_links"] == 12
    assert r["nominal_findings"] == [[], []]
    by_kind = {g["kind"]: g for g in r["damages"]}
    assert all(by_kind[k]["first_right"] for k in ("imu_rotated", "axis_changed", "backlash"))
    assert "dead band grew from" in by_kind["backlash"]["findings"][0]["detail"]
    for kind in ("imu_rotated", "axis_changed"):
        change, limit = bench._change(by_kind[kind]["findings"][0]["detail"])
        assert 1.7 < change < 2.3 and limit < 0.5, (kind, change, limit)
    p = d["pooled"]
    assert (p["robot"], p["n_base"], p["n_recent"], p["nominal_windows"]) == ("ur5e", 40, 20, 22)
    assert p["nominal_findings"] == [[]] * 22
    # the IMU with the longest lever arm (an upper-arm one, about 0.2 m) and the wrist's last IMU
    assert [g["imu"] for g in p["slides"]][1] == "imu11" and p["slides"][0]["lever_arm_mm"] > 150
    assert all(len(g["scatter_mm"]) == 3 and g["other_findings"] == 0 for g in p["slides"])
    s = d["service"]
    assert s["cycles"] == 36 and s["alerts_raised"] == [] and s["drift_findings"] == 0
    assert s["pool_sizes"] == [40, 20]
    assert s["drift_finding_details"] == []
    # the product's schedule (the suite turns it off): the networks retrained every 12 cycles
    assert s["network_interval_cycles"] == 12 and s["network_retrains"] >= 3
    assert s["geometry_comparisons"] >= 3 and s["geometry_kept"] == {"ur5e-0": True}
    assert s["slide_comparisons"] == 0  # 36 cycles: the pool of 40 is far from full
    text = md.read_text()
    assert "| ur5e | 12 / 12 | 0 (2) | imu_rotated 2 ° imu:imu11 | yes |" in text
    assert "0 alerts raised" in text and "networks every 12 cycles" in text
    assert f"{s['geometry_comparisons']} geometry comparisons (0 of them with the lever arms)" in text
    assert "slides judged on pools of 40 and 20 estimates" in text
    assert (
        "Pooled slides (ur5e): the lever arms of the first 40 windows against the mean of the newest k, "
        "for every k up to 20" in text
    )
    assert (tmp_path / "drift.png").stat().st_size > 5000


def test_the_service_part_splits_the_fleet_over_processes(tmp_path: Path) -> None:
    # each robot in a process of its own: the same cycles for each, the counts added, every robot's
    # baseline and geometry kept; a robot's data do not depend on the others (the farm's seeds)
    args = ["--robots", "ur5e", "--parts", "service", "--fleet", "ur5e,ur5e", "--hours", "0.03"]
    md = bench.run(_args(*args, "--networks", "12", "--jobs", "2", "--out", str(tmp_path)))
    s = json.loads((tmp_path / "drift.json").read_text())["service"]
    assert s["processes"] == 2 and s["fleet"] == {"ur5e-0": "ur5e", "ur5e-1": "ur5e"}
    assert s["cycles"] == 22 and s["baseline_cycle"] == {"ur5e-0": 8, "ur5e-1": 8}
    assert s["geometry_kept"] == {"ur5e-0": True, "ur5e-1": True}
    assert s["network_retrains"] == 2 * 2 and s["geometry_comparisons"] >= 2
    assert s["alerts_raised"] == [] and s["drift_findings"] == 0
    assert "CPU s (the sum of 2 processes, the fleet's robots split over them)" in md.read_text()


def test_parts_from_an_earlier_run_must_come_from_the_same_command(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the service part alone would take an hour: a run that takes its parts from earlier runs only
    # renders them, and refuses those of other arguments or of the other frame (here the gyros')
    monkeypatch.setenv("BODYHEALTH_KINEMATICS_ACCELEROMETER_FRAME", "false")
    args = ["--robots", "ur5e", "--hours", "0.05", "--parts", "", "--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit, match="unknown parts"):
        bench.run(_args(*args, "--parts", "catalog,geometry"))
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    service = {"fleet": {"ur5e-0": "ur5e"}, "hours": 0.05, "cycles": 36, "interval_s": 5.0}
    service |= {"kinematics_interval_cycles": 6, "network_interval_cycles": 0, "geometry_comparisons": 5}
    service |= {"drift_findings": 0, "alerts_raised": [], "cpu_s": 1.0}
    data = {"command": "", "machine": "elsewhere", "catalog": [], "pooled": None, "service": service}
    bench.run(_args(*args))  # nothing run, nothing taken: an empty table
    data["command"] = json.loads((tmp_path / "out" / "drift.json").read_text())["command"]
    (earlier / "drift.json").write_text(json.dumps(data))
    text = bench.run(_args(*args, "--from", str(earlier))).read_text()
    assert "5 geometry comparisons, 0 drift findings, 0 alerts raised" in text
    # written before the pool sizes were recorded: the defaults of then
    assert "slides judged on pools of 40 and 20 estimates" in text
    # written before the frame was recorded: the gyros', as set; the part says where it ran
    assert "1 CPU s (run on elsewhere, taken with `--from`)." in text
    for key, value in (("command", data["command"] + " --seed 1"), ("accelerometer_frame", True)):
        (earlier / "drift.json").write_text(json.dumps({**data, key: value}))
        with pytest.raises(SystemExit, match="another command or frame"):
            bench.run(_args(*args, "--from", str(earlier)))


def test_each_window_is_searched_about_the_lag_the_one_before_measured() -> None:
    # encoder stamps 120 ms behind the IMU's (an hour of two clocks 30 ppm apart, plus the skew): the
    # ±100 ms search finds a wrong peak of the quadruped's repeating gait in the second window, the
    # search centred on the lag the first window measured (as the worker centres it) finds the lag
    from dataclasses import replace

    from bodyschema.timing import measured_lag
    from simulators.farm import Farm
    from simulators.sensing import PRESETS

    farm = Farm({"r": "quadruped"}, seed=0, sensing=replace(PRESETS["robot"], skew=0.12))
    first = measured_lag(bench.window_tree(farm.advance(30.0)["r"]))
    rec = farm.advance(30.0)["r"]
    assert first == pytest.approx(0.1257, abs=0.002)
    assert measured_lag(bench.window_tree(rec)) < 0.0
    assert measured_lag(bench.window_tree(rec, None, first)) == pytest.approx(0.1266, abs=0.002)
