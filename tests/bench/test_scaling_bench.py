"""``bodyhealth bench scaling`` on small sizes: each point is the robot it says, estimated exactly."""

from __future__ import annotations

import argparse
import json

from bench import scaling as bench


def test_small_scaling_run(tmp_path) -> None:
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    args = p.parse_args(
        [
            "--joints",
            "3,6",
            "--imus-per-link",
            "1,3",
            "--seconds",
            "5,10",
            "--repeats",
            "1",
            "--out",
            str(tmp_path),
        ]
    )
    md = bench.run(args).read_text()
    series = json.loads((tmp_path / "scaling.json").read_text())["series"]
    assert [(r["joints"], r["imus"], r["samples"]) for r in series["joints"]] == [(3, 4, 6000), (6, 7, 6000)]
    assert [(r["joints"], r["imus"]) for r in series["imus"]] == [(10, 11), (10, 31)]
    assert [r["samples"] for r in series["samples"]] == [500, 1000]
    assert all(r["exact"] and r["cpu_s"] > 0 for rows in series.values() for r in rows)
    assert "| IMUs K | 11 | 31 |" in md and "| samples T | 500 | 1,000 |" in md
    assert (tmp_path / "scaling.png").stat().st_size > 5000
