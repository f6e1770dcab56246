"""The block-robust evidence per effect and channel: calibrated on correlated noise, and its detection
limit means what it says.

Calibration, measured with ``python -m tests.bodyschema.test_discrepancy_evidence 1000`` (seeds
0-999) on 30 s of smooth random rotation at 100 Hz, nothing hidden, noise gyro 0.01 rad/s and acc
0.05 m/s²: the share of p < 0.01 per effect and channel was 0.006-0.019 with AR(1) noise of
correlation 0.95 per sample (time constant 0.2 s) and 0.007-0.017 with white noise, against 0.01
nominal (the binomial standard error of a share of 0.01 over 1,000 seeds is 0.003; 15 blocks for 3
parameters make the F test slightly liberal for the acc scale). The tests below use
fixed seeds.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from bodyschema.discrepancy import analyze
from bodyschema.discrepancy.evidence import effect_evidence
from bodyschema.discrepancy.fit import prepare
from bodyschema.rigid_motion import reference_motion, smooth_random_motion

EFFECTS = ("time_offset", "gyro_bias", "acc_bias", "gyro_scale", "acc_scale", "lever_arm")


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], std: float, rho: float) -> np.ndarray:
    return lfilter([1.0], [1.0, -rho], rng.normal(0.0, std * np.sqrt(1.0 - rho**2), shape), axis=0)


def _recording(seed: int, rho: float = 0.95, gyro_offset: np.ndarray | None = None):
    rng = np.random.default_rng(seed)
    m = smooth_random_motion(30.0, 100.0, rng)
    ref = reference_motion(m["t"], m["quat"], m["pos"], cutoff=None)
    gyro = m["gyro"] + _ar1(rng, m["gyro"].shape, 0.01, rho)
    if gyro_offset is not None:
        gyro = gyro + gyro_offset
    acc = m["acc"] + _ar1(rng, m["acc"].shape, 0.05, rho)
    return ref, gyro, acc


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_correlated_noise_alone_gives_no_evidence(seed: int) -> None:
    ref, gyro, acc = _recording(seed)
    tests = effect_evidence(prepare(ref, gyro, acc, cutoff=None), {}, [], EFFECTS)
    # one test per effect and channel it moves: time offset on both, the rest on one
    assert sorted((e.effect, e.channel) for e in tests) == sorted(
        [("time_offset", "gyro"), ("time_offset", "acc"), ("gyro_bias", "gyro"), ("acc_bias", "acc"),
         ("gyro_scale", "gyro"), ("acc_scale", "acc"), ("lever_arm", "acc")]
    )  # fmt: skip
    assert min(e.p_value for e in tests) > 0.01 / len(tests), [(e.effect, e.p_value) for e in tests]


def test_a_sample_by_sample_test_would_call_the_same_noise_significant() -> None:
    """What the blocks buy: with every sample its own block, the correlated noise looks like evidence."""
    ref, gyro, acc = _recording(0)
    prob = prepare(ref, gyro, acc, cutoff=None)
    robust = {(e.effect, e.channel): e.p_value for e in effect_evidence(prob, {}, [], EFFECTS)}
    naive = {(e.effect, e.channel): e.p_value for e in effect_evidence(prob, {}, [], EFFECTS, block_s=0.01)}
    assert min(naive.values()) < 1e-6 and min(robust.values()) > 1e-3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_three_times_the_detection_limit_is_found_and_measured(seed: int) -> None:
    """The limit is for the weakest direction: a bias of three times it, in that direction, is
    found at the level it refers to, and its estimate lies within 3 standard errors of the truth."""
    ref, gyro, acc = _recording(seed)
    prob = prepare(ref, gyro, acc, cutoff=None)
    (null,) = effect_evidence(prob, {}, [], ["gyro_bias"])
    bias = 3.0 * null.detection_limit * np.array([1.0, -1.0, 1.0]) / np.sqrt(3.0)
    ref, gyro, acc = _recording(seed, gyro_offset=bias)
    (ev,) = effect_evidence(prepare(ref, gyro, acc, cutoff=None), {}, [], ["gyro_bias"])
    assert ev.p_value < ev.alpha
    assert ev.detection_limit == pytest.approx(null.detection_limit, rel=0.05)
    assert np.all(np.abs(np.subtract(ev.estimate, bias)) < 3.0 * np.asarray(ev.stderr))


def test_the_report_carries_every_effect_and_an_interval_for_each_named_one() -> None:
    rng = np.random.default_rng(5)
    m = smooth_random_motion(30.0, 100.0, rng)
    gyro = m["gyro"] + [0.0, 0.05, 0.0] + rng.normal(0.0, 0.01, m["gyro"].shape)
    acc = m["acc"] + rng.normal(0.0, 0.05, m["acc"].shape)
    rep = analyze(reference_motion(m["t"], m["quat"], m["pos"], cutoff=10.0), gyro, acc)
    assert [n for n in rep.names if n != "noise"] == ["gyro_bias"]
    (lo, hi) = rep.cause("gyro_bias").interval[1]
    assert lo < 0.05 < hi and hi - lo < 0.01
    assert {e["effect"] for e in rep.evidence} == set(rep.settings["effects"])
    limit = rep.detection_limit("gyro_scale")
    assert limit is not None and 0 < limit < 0.05


def _sweep(n: int, rho: float) -> dict[tuple[str, str], float]:
    """Share of p < 0.01 per effect and channel over ``n`` seeds of the null (the calibration above)."""
    hits: dict[tuple[str, str], list[bool]] = {}
    for seed in range(n):
        ref, gyro, acc = _recording(seed, rho)
        for e in effect_evidence(prepare(ref, gyro, acc, cutoff=None), {}, [], EFFECTS):
            hits.setdefault((e.effect, e.channel), []).append(e.p_value < 0.01)
    return {k: float(np.mean(v)) for k, v in hits.items()}


if __name__ == "__main__":
    import sys

    for rho in (0.95, 0.0):
        for key, share in _sweep(int(sys.argv[1]) if len(sys.argv) > 1 else 1000, rho).items():
            print(f"rho {rho}", *key, f"{share:.3f}")
