"""Hide one effect at random in a simulated recording: the analysis must name it and measure it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodyschema.discrepancy import EFFECT_NAMES, analyze
from bodyschema.discrepancy.hidden import draw, hide_effect
from bodyschema.rigid_motion import reference_motion, smooth_random_motion


def _motion(rng: np.random.Generator) -> dict[str, np.ndarray]:
    # Generated at 8x the recorded rate so that injected effects (a time shift interpolates) act
    # like on a continuous signal; the recording is every 8th sample (100 Hz).
    return smooth_random_motion(30.0, 800.0, rng, max_rate=3.0, max_accel=2.0, oversample=1)


def _hide(effect: str, true: dict, m: dict, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """(t, quat, pos, gyro, acc) at 100 Hz with ``effect`` injected at the generation rate."""
    gyro, acc = hide_effect(effect, true, m["t"], m["gyro"], m["acc"], m["quat"], rng)
    if effect == "noise":  # noise is white at the recorded rate: add it after decimation
        gyro, acc = m["gyro"], m["acc"]
    s = slice(0, None, 8)
    t, gyro, acc = m["t"][s], gyro[s], acc[s]
    if effect == "noise":
        gyro, acc = hide_effect(effect, true, t, gyro, acc, m["quat"][s], rng)
    return t, m["quat"][s], m["pos"][s], gyro, acc


#: Tolerance of each fitted parameter. Measured: the largest error over 20 seeds (1000-1019) of the
#: single-effect case below, every one named exactly, was 2.5e-6 s (time offset), 5.2e-4 rad/s (gyro
#: bias), 4.0e-4 m/s² (acc bias), 1.6e-5 (gains), 0.003° (mounting), 2.8e-5 m (lever arm), 6.5e-4
#: m/s² (gravity), 4.9 % (noise std); the time offset + lever arm pair (seeds 2000-2019): 2.3e-6 s
#: and 8.8e-5 m. Each tolerance is 2-10x the largest error measured (the gyro bias and the noise,
#: limited by the noise and by the 30 s of data, get 2x).
TOL: dict[str, float] = {
    "time_offset": 2e-5,
    "gyro_bias": 1e-3,
    "acc_bias": 2e-3,
    "gyro_scale": 1e-4,
    "acc_scale": 1e-4,
    "mounting_rotation": 0.02,  # degrees
    "lever_arm": 2e-4,
    "gravity": 3e-3,
    "noise": 0.1,  # relative
}


def check_params(effect: str, true: dict, got: dict, scale: float = 1.0) -> None:
    """Fitted vs injected parameters within :data:`TOL` (``scale`` loosens it: several effects at once)."""
    tol = TOL[effect] * scale
    if effect == "time_offset":
        assert got["seconds"] == pytest.approx(true["seconds"], abs=tol)
    elif effect in ("gyro_bias", "acc_bias", "gravity"):
        assert np.allclose(got["vector"], true["vector"], atol=tol, rtol=0.0)
    elif effect in ("gyro_scale", "acc_scale"):
        assert np.allclose(got["matrix"], true["matrix"], atol=tol, rtol=0.0)
    elif effect == "mounting_rotation":
        err = Rotation.from_rotvec(got["rotvec"]).inv() * Rotation.from_rotvec(true["rotvec"])
        assert np.degrees(err.magnitude()) < tol
    elif effect == "lever_arm":
        assert np.allclose(got["meters"], true["meters"], atol=tol, rtol=0.0)
    elif effect == "noise":
        rate = got["rate_hz"]
        want = np.concatenate([true["gyro_density"], true["acc_density"]]) * np.sqrt(rate)
        assert np.allclose(got["std"], want, rtol=tol, atol=0.0)
    else:  # pragma: no cover
        raise AssertionError(effect)


@pytest.mark.parametrize("effect", EFFECT_NAMES)
def test_a_hidden_effect_is_named_and_measured(effect: str, rng: np.random.Generator) -> None:
    m = _motion(rng)
    true = draw(effect, rng)
    t, quat, pos, gyro, acc = _hide(effect, true, m, rng)
    ref = reference_motion(t, quat, pos, m["gravity"], cutoff=10.0)
    rep = analyze(ref, gyro, acc)
    assert rep.names == [effect], f"injected {effect} {true}, named {rep.names}"
    check_params(effect, true, rep.params[effect])
    cause = rep.cause(effect)
    if effect != "noise":
        # the held-out gain is most of the residual, and significant over the blocks
        assert cause.gain > 0.9
        assert cause.p_value < 0.01
        assert rep.held_out["score_after"] < 0.1 * rep.held_out["score_before"]


def test_nothing_is_named_in_a_clean_recording(rng: np.random.Generator) -> None:
    m = _motion(rng)
    s = slice(0, None, 8)
    ref = reference_motion(m["t"][s], m["quat"][s], m["pos"][s], m["gravity"], cutoff=10.0)
    rep = analyze(ref, m["gyro"][s], m["acc"][s])
    assert rep.names == []
    assert rep.held_out["score_after"] == rep.held_out["score_before"]
    assert rep.residual_before["gyro_rms"] < 2e-3 and rep.residual_before["acc_rms"] < 2e-2


@pytest.mark.slow
def test_two_hidden_effects_are_both_named(rng: np.random.Generator) -> None:
    m = _motion(rng)
    gyro, acc = m["gyro"], m["acc"]
    truths = {e: draw(e, rng) for e in ("time_offset", "lever_arm")}
    # the lever arm sits on the body, the time offset delays what the sensor reports
    gyro, acc = hide_effect("lever_arm", truths["lever_arm"], m["t"], gyro, acc, m["quat"], rng)
    gyro, acc = hide_effect("time_offset", truths["time_offset"], m["t"], gyro, acc, m["quat"], rng)
    s = slice(0, None, 8)
    ref = reference_motion(m["t"][s], m["quat"][s], m["pos"][s], m["gravity"], cutoff=10.0)
    gyro, acc = gyro[s], acc[s]
    rep = analyze(ref, gyro, acc)
    assert set(rep.names) == set(truths)
    for e, p in truths.items():
        check_params(e, p, rep.params[e], scale=2.0)
    assert sum(c.gain for c in rep.causes) > 0.95


def test_unknown_effects_and_bad_shapes_are_refused(rng: np.random.Generator) -> None:
    m = smooth_random_motion(5.0, 100.0, rng)
    ref = reference_motion(m["t"], m["quat"], m["pos"])
    with pytest.raises(ValueError, match="unknown"):
        analyze(ref, m["gyro"], m["acc"], effects=["gyro_bias", "warp_drive"])
    with pytest.raises(ValueError, match="shape"):
        analyze(ref, m["gyro"][:-1], m["acc"])
    bad = m["gyro"].copy()
    bad[:] = np.nan
    with pytest.raises(ValueError, match="no sample"):
        analyze(ref, bad, m["acc"])
