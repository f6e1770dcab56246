"""``bodyhealth bench writes`` on a short run: table, JSON and plot, and amplification that falls as the
commit interval grows (the journal holds every frame byte at least once)."""

from __future__ import annotations

import json
from pathlib import Path

from bench import writes as bench
from tests.bench.args import bench_args


def test_bench_writes_measures_amplification_against_the_interval(tmp_path: Path) -> None:
    args = bench_args(
        bench,
        *[
            "--seconds",
            "3",
            "--robots",
            "2",
            "--intervals",
            "0,1",
            "--backends",
            "sqlite",
            "--out",
            str(tmp_path),
        ],
    )
    assert bench.run(args) == tmp_path / "writes.md"
    data = json.loads((tmp_path / "writes.json").read_text())
    assert (tmp_path / "writes.png").stat().st_size > 1000 and data["default_interval_s"] == 1.0
    rows = {r["commit_interval_s"]: r for r in data["rows"]}
    assert set(rows) == {0.0, 1.0} and {r["backend"] for r in rows.values()} == {"sqlite"}
    for r in rows.values():
        # 2 robots x 3 s x 100 Hz, each sample 8 bytes x (t + 6 joints + 7 IMUs x 6)
        assert r["frame_bytes"] == 2 * 300 * 8 * (1 + 6 + 42)
        assert 1.0 <= r["journal_amplification"] <= r["total_amplification"]
    assert rows[1.0]["transactions"] < rows[0.0]["transactions"]
    assert rows[1.0]["journal_amplification"] < rows[0.0]["journal_amplification"]
    assert "| sqlite | 1 s (default) |" in (tmp_path / "writes.md").read_text()
