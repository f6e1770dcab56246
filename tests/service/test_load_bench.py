"""``bodyhealth bench load`` on a short run: the demo service under locust's mixed reads, with the table,
JSON and plot written and values that can only come from a real run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import load as bench
from tests.bench.args import bench_args

pytestmark = [pytest.mark.slow, pytest.mark.e2e]


def test_bench_load_measures_latency_while_the_farm_ingests(tmp_path: Path) -> None:
    args = bench_args(bench, *["--rps", "20", "--seconds", "6", "--warmup", "2", "--out", str(tmp_path)])
    assert bench.run(args) == tmp_path / "load.md"
    data = json.loads((tmp_path / "load.json").read_text())
    assert (tmp_path / "load.png").stat().st_size > 1000
    assert (data["target_rps"], data["target_p99_ms"]) == (200.0, 20.0)
    (row,) = data["rows"]
    assert row["offered_rps"] == 20.0 and row["failures"] == 0
    # locust paces 2 users at 10 rps each: about 120 requests in 6 s
    assert 60 <= row["requests"] <= 180 and 10.0 <= row["achieved_rps"] <= 30.0
    assert 0 < row["p50_ms"] <= row["p95_ms"] <= row["p99_ms"] <= row["max_ms"]
    # the farm kept ingesting meanwhile: three robots at 100 Hz, nothing dropped
    assert row["frames_stored_per_s"] > 50 and row["frames_dropped"] == 0
    assert row["service_cpu_per_s"] > 0
