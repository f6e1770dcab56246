"""``bodyhealth bench lever_budget``: the IMU model's effects taken out one at a time show which of them
makes one window's lever arms scatter; the run writes its table, JSON and plot."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from bench import lever_budget as bench

pytestmark = pytest.mark.slow


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    return p.parse_args(list(argv))


def test_conditions_drop_or_keep_the_named_effects() -> None:
    full = [e for e, _ in bench._imu_model(None).effects]
    assert "gyro_scale" in full and "noise" in full
    assert [e for e, _ in bench._imu_model("-gyro_scale").effects] == [e for e in full if e != "gyro_scale"]
    assert [e for e, _ in bench._imu_model("+noise").effects] == ["noise"]
    assert bench._imu_model("+").effects == ()


def test_short_run_tells_the_gyro_sensitivity_from_an_ideal_imu(tmp_path: Path) -> None:
    """Seed 0, four windows of the UR5e (fixed, so the numbers are the same on every run)."""
    conds = "MPU-6050,without gyro_scale,ideal IMU"
    md = bench.run(_args("--windows", "4", "--conditions", conds, "--out", str(tmp_path)))
    d = json.loads((tmp_path / "lever-budget.json").read_text())
    assert list(d["conditions"]) == conds.split(",")
    assert (tmp_path / "lever-budget.png").stat().st_size > 10_000
    frames = ("gyro", "accelerometer")
    s = {c: {f: bench.summary(d["conditions"][c], f) for f in frames} for c in d["conditions"]}
    for frame in frames:
        assert s["MPU-6050"][frame]["imus"] == 12
        # an ideal IMU leaves the estimator's own floor: well under a millimetre, and as stated
        assert s["ideal IMU"][frame]["scatter_median_mm"] < 1.0
        assert s["ideal IMU"][frame]["understated"] == 0
        assert s["MPU-6050"][frame]["scatter_max_mm"] > 3.0 * s["ideal IMU"][frame]["scatter_max_mm"]
    # in the gyros' frame the gyro's sensitivity errors make the largest scatter, which is not stated;
    # on the wrist (imu8-11, about 30 mm from their axes) they make most of it
    g = d["conditions"]["MPU-6050"]["frames"]["gyro"]
    worst = max(g, key=lambda n: g[n]["scatter_mm"])
    assert g[worst]["scatter_mm"] > 2.0 * g[worst]["stated_mm"]
    without = d["conditions"]["without gyro_scale"]["frames"]["gyro"]
    wrist = [f"imu{i}" for i in range(8, 12)]
    assert sum(without[n]["scatter_mm"] for n in wrist) < 0.5 * sum(g[n]["scatter_mm"] for n in wrist)
    text = md.read_text()
    assert d["command"] in text and "| without gyro_scale | gyro |" in text


def test_unknown_condition_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="unknown conditions"):
        bench.run(_args("--conditions", "MPU-6050,no such", "--out", str(tmp_path)))
    with pytest.raises(SystemExit, match="at least 3"):
        bench.run(_args("--windows", "2", "--out", str(tmp_path)))
