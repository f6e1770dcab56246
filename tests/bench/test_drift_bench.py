"""``bodyhealth bench drift``, its catalog part: a short run finds each 2° damage first on its part,
raises nothing on a healthy robot, and writes its table, JSON and plot. The pooled and service parts
run in tests of their own (test_drift_bench_pooled.py, test_drift_bench_service.py), so that the
suite's workers share them out."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import drift as bench
from tests.bench.args import bench_args

pytestmark = pytest.mark.slow


def test_catalog_part_finds_each_damage_first_on_its_part(tmp_path: Path) -> None:
    argv = ["--robots", "ur5e", "--nominal", "2", "--slide-mm", "5", "--parts", "catalog"]
    md = bench.run(bench_args(bench, *argv, "--out", str(tmp_path)))
    d = json.loads((tmp_path / "drift.json").read_text())
    (r,) = d["catalog"]
    assert d["pooled"] is None and d["service"] is None
    assert r["robot"] == "ur5e" and r["axis_converged"] == r["imus_on_links"] == 12
    assert r["nominal_findings"] == [[], []]
    by_kind = {g["kind"]: g for g in r["damages"]}
    assert [g["kind"] for g in r["damages"]] == ["imu_rotated", "axis_changed", "backlash", "imu_shifted"]
    assert all(by_kind[k]["first_right"] for k in ("imu_rotated", "axis_changed", "backlash"))
    assert "dead band grew from" in by_kind["backlash"]["findings"][0]["detail"]
    for kind in ("imu_rotated", "axis_changed"):
        change, limit = bench._change(by_kind[kind]["findings"][0]["detail"])
        assert 1.7 < change < 2.3 and limit < 0.5, (kind, change, limit)
    text = md.read_text()
    assert "| ur5e | 12 / 12 | 0 (2) | imu_rotated 2 ° imu:imu11 | yes |" in text
    assert "Pooled slides" not in text and "The worker's real cycle" not in text
    assert (tmp_path / "drift.png").stat().st_size > 5000


def test_parts_from_an_earlier_run_must_come_from_the_same_command(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the service part alone would take an hour: a run that takes its parts from earlier runs only
    # renders them, and refuses those of other arguments or of the other frame (here the gyros')
    monkeypatch.setenv("BODYHEALTH_KINEMATICS_ACCELEROMETER_FRAME", "false")
    args = ["--robots", "ur5e", "--hours", "0.05", "--parts", "", "--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit, match="unknown parts"):
        bench.run(bench_args(bench, *args, "--parts", "catalog,geometry"))
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    service = {"fleet": {"ur5e-0": "ur5e"}, "hours": 0.05, "cycles": 36, "interval_s": 5.0}
    service |= {"kinematics_interval_cycles": 6, "network_interval_cycles": 0, "geometry_comparisons": 5}
    service |= {"drift_findings": 0, "alerts_raised": [], "cpu_s": 1.0}
    data = {"command": "", "machine": "elsewhere", "catalog": [], "pooled": None, "service": service}
    bench.run(bench_args(bench, *args))  # nothing run, nothing taken: an empty table
    data["command"] = json.loads((tmp_path / "out" / "drift.json").read_text())["command"]
    (earlier / "drift.json").write_text(json.dumps(data))
    text = bench.run(bench_args(bench, *args, "--from", str(earlier))).read_text()
    assert "5 geometry comparisons, 0 drift findings, 0 alerts raised" in text
    # written before the pool sizes were recorded: the defaults of then
    assert "slides judged on pools of 40 and 20 estimates" in text
    # written before the frame was recorded: the gyros', as set; the part says where it ran
    assert "1 CPU s (run on elsewhere, taken with `--from`)." in text
    for key, value in (("command", data["command"] + " --seed 1"), ("accelerometer_frame", True)):
        (earlier / "drift.json").write_text(json.dumps({**data, key: value}))
        with pytest.raises(SystemExit, match="another command or frame"):
            bench.run(bench_args(bench, *args, "--from", str(earlier)))


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
