"""``bodyhealth bench fleet`` on a tiny fleet: real Dask worker processes retrain every robot from its
stored weights while ingest and the API run beside them, and again with the training alone; the table,
JSON and plot agree. The 2-over-1 worker speedups are arithmetic on the rounds' rows: they are checked
on the rows of the stored bench run, so the real run starts one cluster per path, 2 workers beside
ingest+api and 1 alone, instead of a 1- and a 2-worker cluster for each."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import RESULTS_DIR
from bench import fleet as bench
from tests.bench.args import bench_args


def test_speedups_are_two_workers_over_one_per_fleet_size_on_the_stored_run() -> None:
    stored = json.loads((RESULTS_DIR / "fleet.json").read_text(encoding="utf-8"))
    rows = stored["rows"]
    for beside, key in ((bench.LOADED, "speedup_2_over_1"), (bench.ALONE, "speedup_2_over_1_alone")):
        got = bench.speedups(rows, beside)
        assert {str(n): s for n, s in got.items()} == stored[key]
        by = {(r["robots"], r["workers"]): r["retrains_per_hour"] for r in rows if r["beside"] == beside}
        for n, s in got.items():  # the ratio of the rounds' rates, to the 2 decimals written
            assert s == pytest.approx(by[(n, 2)] / by[(n, 1)], abs=0.005 + 1e-9)
    # a fleet size with only one cluster size has no speedup
    assert bench.speedups([r for r in rows if r["workers"] == 2], bench.LOADED) == {}
    # the sentence the table states them in ("8 robots 1.5x, 32 robots 1.85x, ...")
    loaded, alone = (bench._speedup_text(bench.speedups(rows, b)) for b in (bench.LOADED, bench.ALONE))
    assert loaded.count("robots") == len(stored["speedup_2_over_1"]) > 0
    text = f"with ingest and the API beside: {loaded}; with the training alone: {alone} "
    assert text in (RESULTS_DIR / "fleet.md").read_text(encoding="utf-8")


@pytest.mark.slow
@pytest.mark.e2e
def test_bench_fleet_retrains_every_robot_warm_beside_ingest_and_api_and_alone(
    tmp_path: Path,
) -> None:
    # The bench trains at the service's priority settings: niced, in the suite (tests/conftest.py),
    # so it ends beside work that fills every core; the JSON and the table say which.
    argv = ["--robots", "2", "--workers", "2", "--window", "10", "--recordings", "1"]
    alone = ["--alone", "2", "--alone-workers", "1"]
    args = bench_args(bench, *argv, "--api-rps", "10", *alone, "--out", str(tmp_path))
    assert bench.run(args) == tmp_path / "fleet.md"
    data = json.loads((tmp_path / "fleet.json").read_text())
    assert (tmp_path / "fleet.png").stat().st_size > 1000
    rounds = [(r["robots"], r["workers"], r["beside"]) for r in data["rows"]]
    assert rounds == [(2, 2, "ingest+api"), (2, 1, "none")]
    (cold,) = data["cold"]
    for r in data["rows"]:
        assert r["warm"] == 2  # every retrain started from the robot's stored weights
        # a warm start stops after 3 or 4 epochs; the cold one ran to convergence
        assert r["epochs_median"] <= 4 < cold["epochs"] and 0 < r["cpu_s_median"] <= r["cpu_s_max"]
        # the rate is from the unrounded wall time; wall_s is written to 0.1 s (a round of a few seconds)
        assert r["retrains_per_hour"] == pytest.approx(2 / r["wall_s"] * 3600, rel=0.05 / r["wall_s"] + 1e-3)
    loaded, alone = data["rows"]
    assert "ingest_lag_s_median" not in alone and "api_p99_ms" not in alone
    # ingest kept writing one second per second for both robots (12 IMUs at 100 Hz each)
    assert loaded["ingest_samples_per_s"] > 50 and loaded["ingest_lag_s_median"] < 1.0
    assert loaded["api_failures"] == 0 and 0 < loaded["api_p50_ms"] <= loaded["api_p99_ms"]
    # one cluster size: no speedup to state (the arithmetic is checked on the stored run above)
    assert data["speedup_2_over_1"] == data["speedup_2_over_1_alone"] == {}
    md = (tmp_path / "fleet.md").read_text()
    assert "| 2 | 2 | ingest+api |" in md and "| 2 | 1 | none |" in md
    assert "--alone '2' --alone-workers 1 --seed 0" in data["command"]
    assert "with ingest and the API beside: not measured; with the training alone: not measured" in md
    # the retrains ran at the priority the service's settings give
    assert data["training_priority"] == {"nice": 10, "idle": False}
    assert "the service's priority: nice 10) while" in md
