"""``bench realism`` estimates every cell a second time in its single-clock form, kept apart."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench import realism
from bodyschema.recording import Recording
from tests.bench.args import bench_args


def test_single_clock_pairs_each_imu_sample_with_the_nearest_encoder_sample():
    t = np.arange(50) * 0.01
    t_q = np.arange(-3, 130) * 0.004 + 0.0013  # 250 Hz, offset, starting before and ending before t
    q = np.c_[np.sin(t_q), np.cos(t_q)]
    rec = Recording(
        t=t,
        t_q=t_q,
        joint_names=["a", "b"],
        q=q,
        qd=np.c_[np.cos(t_q), -np.sin(t_q)],
        imu_names=["i"],
        acc=np.ones((50, 1, 3)),
        gyro=np.arange(150.0).reshape(50, 1, 3),
    )
    one = realism.single_clock(rec)
    assert one.t_q is None and one.qd is None and one.qdd is None
    inside = (t >= t_q[0]) & (t <= t_q[-1])
    np.testing.assert_array_equal(one.t, t[inside])
    np.testing.assert_array_equal(one.gyro, rec.gyro[inside])
    nearest = np.abs(t_q[None, :] - one.t[:, None]).argmin(axis=1)
    np.testing.assert_array_equal(one.q, q[nearest])
    assert np.abs(t_q[nearest] - one.t).max() <= 0.002 + 1e-12  # half an encoder period


@pytest.mark.slow
def test_realism_keeps_single_clock_rows_apart(tmp_path):
    args = bench_args(
        realism, "--joints", "4", "--robots", "1", "--seconds", "12", "--methods", "fast",
        "--catalog-seeds", "0", "--out", str(tmp_path),
    )  # fmt: skip
    md = realism.run(args)
    data = json.loads((tmp_path / "realism.json").read_text())
    assert [r["cell"] for r in data["rows"]] == list(realism.CELLS)
    assert all("shape" not in r for r in data["rows"])
    single = data["single_clock_rows"]
    assert [r["cell"] for r in single] == list(realism.CELLS)
    assert {r["shape"] for r in single} == {"single-clock"} and all("skew_err_ms" not in r for r in single)
    s = data["summary"]["fast"]["single_clock"]
    assert s["exact"] + s["undetermined"] + s["wrong"] == s["robots"] == len(realism.CELLS)
    assert sum(c["robots"] for c in s["cells"].values()) == len(realism.CELLS)
    assert "| cell | 4 joints | single-clock |" in md.read_text()
