"""Hidden encoder effects on a simulated UR5e recorded the way a robot records (``robot`` sensing,
MPU-6050 IMUs): the exact set of names and every value within 3 sigma.

The untouched recording names its own time offset only (the IMU's 8 ms skew plus its filter's
4.8 ms delay, and half the clock drift over the run); that set is measured once and kept. Each case
hides effects through the simulator (:func:`bench.sim2real_encoders.analyze_case`) at 3 or 10 times
the untouched recording's own detection limit for them, with a random sign on a random joint that
observes them (seeded), alone, in a pair and in a triple.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.sim2real_encoders import Hidden, analyze_case, draw_cases, score

ROBOT, SECONDS, SEED = "ur5e", 30.0, 3
CASES = 10  # four effects alone at two factors, a pair, a triple

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def null():
    rep, _ = analyze_case(ROBOT, SECONDS, SEED, [])
    return rep


@pytest.fixture(scope="module")
def cases(null) -> list[list[Hidden]]:
    out = draw_cases(null, [3.0, 10.0], 1, 1, np.random.default_rng(SEED))
    assert len(out) == CASES
    return out


def test_the_untouched_recording_names_its_own_time_offset_only(null) -> None:
    assert null.names == ["encoder_time_offset"]
    (tau,) = null.causes
    # skew + gyro filter delay + half the 30 ppm drift over the run, to the filter's own phase
    assert abs(tau.value - (0.008 + 0.0048 + 0.5 * SECONDS * 30e-6)) < 1e-3
    assert not null.limit("encoder_offset[shoulder_pan]").observable  # a turn about gravity
    assert all(x.observable for x in null.not_named if x.name != "encoder_offset[shoulder_pan]")


@pytest.mark.parametrize("index", range(CASES))
def test_a_hidden_encoder_effect_is_named_with_its_value_and_nothing_else(null, cases, index: int) -> None:
    hidden = cases[index]
    rep, cpu = analyze_case(ROBOT, SECONDS, SEED, hidden)
    result = score(rep, null, hidden)
    assert result["extra"] == [], result
    for h in result["hidden"]:
        assert h["named"], (h, rep.names)
        assert h["within"], (h, rep.summary())
    named = {n for c in rep.causes for n in c.name.split(" or ")}
    assert {h.name for h in hidden} | {"encoder_time_offset"} <= named
    assert cpu < 30.0
