"""``bodyhealth bench shapes`` on two small robots: both shapes run, are classified and written out."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench import shapes
from tests.bench.args import bench_args


@pytest.mark.slow
def test_two_small_robots_in_both_shapes_are_written(tmp_path):
    args = bench_args(shapes, "--robots", "2", "--joints", "4,5", "--seconds", "20", "--out", str(tmp_path))
    md = shapes.run(args)
    data = json.loads((tmp_path / "shapes.json").read_text())
    rows = data["rows"]
    assert [(r["robot"], r["shape"]) for r in rows] == [(0, s) for s in shapes.SHAPES] + [
        (1, s) for s in shapes.SHAPES
    ]
    # robot 1 carries a skew (odd index), robot 0 none; both shapes hold the same samples and sensing
    assert rows[0]["skew"] == 0.0 and 0.002 <= rows[2]["skew"] <= 0.01
    assert {r["verdict"] for r in rows} <= {"exact", "undetermined", "wrong"}
    for r in rows:
        assert len(r["axis_deg"]) == len(r["lever_mm"]) == len(r["converged"]) <= r["imus"]
        assert all(0 <= a <= 180 for a in r["axis_deg"])
    s = data["summary"]
    assert set(s) == set(shapes.SHAPES)
    for shape in shapes.SHAPES:
        assert s[shape]["exact"] + s[shape]["undetermined"] + s[shape]["wrong"] == 2
        # the gyro's reading of a joint's axis: within the datasheet's lean (3 % scale, 2 % cross-axis
        # is under 3 degrees) for the median IMU, on robots with 20 s of slow sines
        assert s[shape]["gyro_axis_deg_median"] < 3.0
    text = md.read_text()
    assert "| multi-rate |" in text and "| single-clock |" in text and data["machine"] in text
    assert (tmp_path / "shapes.png").stat().st_size > 5000


def test_conditions_cover_every_combination():
    drawn = [shapes.conditions(i, np.random.default_rng(i)) for i in range(12)]
    seen = {(c["skew"] > 0, c["encoder_bits"], c["dlpf"]) for c in drawn}
    assert len(seen) == 12
