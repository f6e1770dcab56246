"""``bodyhealth bench fleet`` on a tiny fleet: real Dask worker processes retrain every robot from its
stored weights while ingest and the API run beside them, and again with the training alone; the table,
JSON and plot agree."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import fleet as bench
from tests.bench.args import bench_args

pytestmark = [pytest.mark.slow, pytest.mark.e2e]


def test_bench_fleet_retrains_every_robot_warm_on_one_and_two_workers(tmp_path: Path) -> None:
    argv = ["--robots", "2", "--workers", "1,2", "--window", "10", "--recordings", "1"]
    args = bench_args(bench, *argv, "--api-rps", "10", "--alone", "2", "--out", str(tmp_path))
    assert bench.run(args) == tmp_path / "fleet.md"
    data = json.loads((tmp_path / "fleet.json").read_text())
    assert (tmp_path / "fleet.png").stat().st_size > 1000
    rounds = [(r["robots"], r["workers"], r["beside"]) for r in data["rows"]]
    assert rounds == [(2, 1, "ingest+api"), (2, 2, "ingest+api"), (2, 1, "none"), (2, 2, "none")]
    (cold,) = data["cold"]
    for r in data["rows"]:
        assert r["warm"] == 2  # every retrain started from the robot's stored weights
        # a warm start stops after 3 or 4 epochs; the cold one ran to convergence
        assert r["epochs_median"] <= 4 < cold["epochs"] and 0 < r["cpu_s_median"] <= r["cpu_s_max"]
        # the rate is from the unrounded wall time; wall_s is written to 0.1 s (a round of a few seconds)
        assert r["retrains_per_hour"] == pytest.approx(2 / r["wall_s"] * 3600, rel=0.05 / r["wall_s"] + 1e-3)
    alone = [r for r in data["rows"] if r["beside"] == "none"]
    assert all("ingest_lag_s_median" not in r and "api_p99_ms" not in r for r in alone)
    for r in data["rows"][:2]:
        # ingest kept writing one second per second for both robots (12 IMUs at 100 Hz each)
        assert r["ingest_samples_per_s"] > 50 and r["ingest_lag_s_median"] < 1.0
        assert r["api_failures"] == 0 and 0 < r["api_p50_ms"] <= r["api_p99_ms"]
    assert set(data["speedup_2_over_1"]) == set(data["speedup_2_over_1_alone"]) == {"2"}
    for beside in ("ingest+api", "none"):
        by = {r["workers"]: r["retrains_per_hour"] for r in data["rows"] if r["beside"] == beside}
        key = "speedup_2_over_1" if beside == "ingest+api" else "speedup_2_over_1_alone"
        assert data[key]["2"] == pytest.approx(by[2] / by[1], abs=0.006)
    md = (tmp_path / "fleet.md").read_text()
    assert "| 2 | 2 | ingest+api |" in md and "| 2 | 2 | none |" in md
    # the retrains ran as the embedded cluster runs them
    assert data["training_priority"] == {"nice": 10, "idle": True}
    assert "nice 10, Linux's idle scheduling class" in md
