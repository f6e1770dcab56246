"""``bodyhealth bench store`` on a tiny load: it writes its table, JSON and plot with sane numbers."""

from __future__ import annotations

import json

import pytest

from bench import store as bench
from tests.bench.args import bench_args


def test_bench_store_writes_results(tmp_path) -> None:
    args = bench_args(
        bench,
        *[
            "--seconds",
            "3",
            "--imus",
            "4",
            "--joints",
            "2",
            "--window",
            "2",
            "--backends",
            "sqlite",
            "--out",
            str(tmp_path),
        ],
    )
    md = bench.run(args)
    data = json.loads((tmp_path / "store.json").read_text())
    assert md == tmp_path / "store.md" and (tmp_path / "store.png").stat().st_size > 1000
    rows = {r["path"]: r for r in data["rows"]}
    assert set(rows) == {"write_many 1 s", "pipeline"} and data["imus"] == 4
    for r in rows.values():
        assert r["backend"] == "sqlite" and r["device_seconds"] == 3.0
        assert r["wall_seconds"] > 0 and r["cpu_seconds"] > 0
        # the load is 4 IMUs at 100 Hz: 400 IMU samples per device second, whatever the speed was
        assert r["imu_samples_per_s"] / r["realtime_multiple"] == pytest.approx(400.0)
        # 3 s of 4 IMUs take milliseconds to store: far faster than the robot produces them
        assert r["realtime_multiple"] > 1.0
    assert rows["write_many 1 s"]["transactions"] == 3
    # the pipeline writes its 30 batches of 10 frames in at most 30 transactions (it coalesces
    # whatever is queued when the writer comes round, so how many fewer depends on timing)
    assert 1 <= rows["pipeline"]["transactions"] <= 30
    assert rows["pipeline"]["window_read_ms"] > 0
    # At least the 48 bytes of sensor data per IMU sample (plus time stamps, joints, empty pages).
    assert rows["pipeline"]["bytes_per_imu_sample"] >= 48
    text = md.read_text()
    assert "| sqlite | pipeline |" in text and "Machine:" in text
