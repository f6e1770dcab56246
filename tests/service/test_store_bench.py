"""``bodyhealth bench store`` on a tiny load: it writes its table, JSON and plot with sane numbers."""

from __future__ import annotations

import argparse
import json

from service.bench import store as bench


def test_bench_store_writes_results(tmp_path) -> None:
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    args = p.parse_args(
        [
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
        ]
    )
    md = bench.run(args)
    data = json.loads((tmp_path / "store.json").read_text())
    assert md == tmp_path / "store.md" and (tmp_path / "store.png").stat().st_size > 1000
    rows = {r["path"]: r for r in data["rows"]}
    assert set(rows) == {"write_many 1 s", "pipeline"} and data["imus"] == 4
    for r in rows.values():
        assert r["backend"] == "sqlite" and r["device_seconds"] == 3.0
        assert r["realtime_multiple"] == r["device_seconds"] / r["wall_seconds"]
        assert r["imu_samples_per_s"] == 300 * 4 / r["wall_seconds"]
    assert rows["write_many 1 s"]["transactions"] == 3
    # At least the 48 bytes of sensor data per IMU sample (plus time stamps, joints, empty pages).
    assert rows["pipeline"]["bytes_per_imu_sample"] >= 48
    text = md.read_text()
    assert "| sqlite | pipeline |" in text and "Machine:" in text
