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


def test_short_run(tmp_path: Path) -> None:
    md = bench.run(
        _args(
            "--robots",
            "ur5e",
            "--nominal",
            "2",
            "--slide-mm",
            "5",
            "--fleet",
            "ur5e",
            "--hours",
            "0.05",
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
    s = d["service"]
    assert s["cycles"] == 36 and s["alerts_raised"] == [] and s["drift_findings"] == 0
    assert s["geometry_comparisons"] >= 3 and s["geometry_kept"] == {"ur5e-0": True}
    text = md.read_text()
    assert "| ur5e | 12 / 12 | 0 (2) | imu_rotated 2 ° imu:imu11 | yes |" in text
    assert "0 alerts raised" in text
    assert (tmp_path / "drift.png").stat().st_size > 5000
