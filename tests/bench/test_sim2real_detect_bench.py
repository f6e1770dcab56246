"""``bodyhealth bench sim2real_detect`` on one trial and two effects: what it writes, and that its
counts come from real analyses (the hidden effects named and measured on top of the trial's own)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench import sim2real_detect as bench
from tests.bench.args import bench_args
from tests.broad_data import broad_dir, needs_broad

TAP = "25_disturbed_tapping_B"


@pytest.mark.slow
@needs_broad(TAP)
def test_an_effect_hidden_at_three_times_its_limit_is_named_and_measured(tmp_path: Path) -> None:
    argv = ["--data", str(broad_dir()), "--trials", TAP[:3], "--effects", "acc_scale"]
    argv += ["--factors", "3", "--pairs", "0", "--triples", "0", "--jobs", "1", "--out", str(tmp_path)]
    assert bench.run(bench_args(bench, *argv)) == tmp_path / "sim2real-detect.md"
    data = json.loads((tmp_path / "sim2real-detect.json").read_text())
    assert (tmp_path / "sim2real-detect.png").stat().st_size > 1000
    (trial,) = data["trials"]
    assert trial["trial"] == TAP and {"time_offset", "gyro_bias"} <= set(trial["null_names"])
    # the limit is the trial's own, in the effect's units (a gain)
    assert 1e-4 < trial["limits"]["acc_scale"] < 0.05
    cases = {c["hidden"][0]: c for c in trial["cases"]}
    assert set(cases) == {"acc_scale"}
    for effect, case in cases.items():
        assert case["magnitudes"][effect] == pytest.approx(3 * trial["limits"][effect])
        assert case["effects"][effect]["named"] and case["effects"][effect]["within"], case
        assert case["extra"] == [] and 0 < case["cpu_s"] < 60
    rates = data["rates"]
    assert rates["first_factor"] == {"hidden": 1, "named": 1, "named_within": 1, "named_joint": 0}
    assert "1 of 1 hidden effects (100.0 %)" in (tmp_path / "sim2real-detect.md").read_text()


def test_an_injected_change_has_the_asked_size_in_a_random_direction() -> None:
    g = np.array([0.0, 0.0, -9.81])
    rng = np.random.default_rng(1)
    for effect in ("time_offset", "gyro_bias", "acc_scale", "mounting_rotation", "lever_arm"):
        p = bench.inject(effect, 0.02, rng, g)
        value = np.atleast_1d(np.asarray(next(iter(p.values())), dtype=float))
        change = value - 1.0 if effect == "acc_scale" else value
        assert np.linalg.norm(change) == pytest.approx(0.02)
    tilted = np.asarray(bench.inject("gravity", 0.05, rng, g)["vector"])
    # a tilt: the magnitude kept, the tip moved by 0.05 m/s²
    assert np.linalg.norm(tilted) == pytest.approx(9.81) and np.linalg.norm(tilted - g) == pytest.approx(
        0.05, rel=1e-3
    )
