"""The floating-base maths on synthetic legs with known answers (bodyschema.floating_base, .contacts,
.floating_effects). Tolerances: exact relations hold to float rounding (1e-9); finite differences at
step h to their O(h²) error; estimates from noise to their stated standard error."""

from __future__ import annotations

import numpy as np
import pytest

from bodyschema.contacts import force_contacts, ramp_time, transition_weights
from bodyschema.floating_base import (
    FootMotion,
    SerialChain,
    body_reference,
    chain_motion,
    derivative,
    flat_foot_gravity,
    foot_plane_gravity,
    quantization_floor,
    stance_twist,
)
from bodyschema.floating_effects import forward_select, linear_effect
from bodyschema.imu_effects import specific_force
from bodyschema.rigid_motion import lowpass

G = np.array([0.0, 0.0, -9.81])


def _planar_leg() -> SerialChain:
    """Hip and knee about y, 0.4 m links down from the IMU, the sole 0.05 m below the ankle, then
    an ankle about y: the foot's frame turns with all three."""
    T = np.eye(4)
    down = np.eye(4)
    down[2, 3] = -0.4
    tip = np.eye(4)
    tip[2, 3] = -0.05
    y = np.array([0.0, 1.0, 0.0])
    return SerialChain(np.stack([T, down, down]), np.stack([y, y, y]), (0, 1, 2), tip)


def _leg_motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = np.stack([0.3 * np.sin(1.7 * t), -0.6 + 0.4 * np.sin(2.3 * t + 0.4), 0.2 * np.cos(1.1 * t)], axis=1)
    qd = np.stack(
        [0.3 * 1.7 * np.cos(1.7 * t), 0.4 * 2.3 * np.cos(2.3 * t + 0.4), -0.2 * 1.1 * np.sin(1.1 * t)], 1
    )
    return q, qd


def test_flat_stance_foot_gives_the_exact_gyro_and_velocity() -> None:
    """A planar leg on a flat foot: the base turns at minus the sum of the joint rates about y, and
    its velocity is the derivative of its position seen from the foot (the foot frame is the world)."""
    t = np.arange(0.0, 4.0, 1e-3)
    q, qd = _leg_motion(t)
    foot = chain_motion(_planar_leg(), q, qd, flat=True)
    w, v, seen = stance_twist([foot], np.ones((t.size, 1)))
    assert seen.all()
    # Exact but for the fill's pull towards 0 (FILL_WEIGHT = 1e-6 of a foot's unit weight).
    np.testing.assert_allclose(w, np.c_[np.zeros(t.size), -qd.sum(axis=1), np.zeros(t.size)], atol=1e-5)
    # The IMU in the foot frame: R_fi = R_if^T, p_fi = -R_if^T p_if; v = R_fi^T d(p_fi)/dt.
    R_fi = np.swapaxes(foot.R, 1, 2)
    p_fi = -np.einsum("tij,tj->ti", R_fi, foot.p)
    v_num = np.einsum("tji,tj->ti", R_fi, np.gradient(p_fi, t, axis=0))
    inner = slice(2, -2)  # central differences: O(h²) ~ 1e-6 m/s at h = 1 ms for these rates
    np.testing.assert_allclose(v[inner], v_num[inner], atol=1e-5)


def test_flat_foot_specific_force_matches_the_foot_frame_motion() -> None:
    """body_reference from the stance twist and the flat foot's gravity reads what an ideal IMU moving
    as seen from the foot frame reads: R^T (a - g)."""
    t = np.arange(0.0, 6.0, 0.005)
    q, qd = _leg_motion(t)
    foot = chain_motion(_planar_leg(), q, qd, flat=True)
    w, v, _ = stance_twist([foot], np.ones((t.size, 1)))
    ref = body_reference(t, w, v, flat_foot_gravity([foot], np.ones((t.size, 1)), G), G, None)
    R_fi = np.swapaxes(foot.R, 1, 2)
    p_fi = -np.einsum("tij,tj->ti", R_fi, foot.p)
    acc = derivative(t, derivative(t, p_fi))
    expect = np.einsum("tji,tj->ti", R_fi, acc - G)
    got = specific_force(ref.R, ref.acc_world, ref.gravity)
    inner = slice(20, -20)  # the quintic spline's end effects
    np.testing.assert_allclose(got[inner], expect[inner], atol=2e-3)


def _point(p: list[float]) -> FootMotion:
    T = 5
    return FootMotion(
        np.tile(np.eye(3), (T, 1, 1)), np.tile(p, (T, 1)), np.zeros((T, 3)), np.zeros((T, 3)), False
    )


def test_point_feet_fix_rotation_only_off_their_line() -> None:
    """Two still point feet on the x axis leave the rate about x free (taken from the fill); three
    not on one line fix all of it (the fill is ignored)."""
    fill = np.tile([0.7, 0.2, -0.3], (5, 1))
    two = [_point([0.3, 0.0, -0.3]), _point([-0.3, 0.0, -0.3])]
    w, v, seen = stance_twist(two, np.ones((5, 2)) / 2, fill)
    assert seen[:, 0].sum() == 0 and seen[:, 1:].all()
    np.testing.assert_allclose(w[:, 1:], 0.0, atol=1e-5)
    # The free direction mixes w and v; the weak pull that keeps v finite takes 1e-4 of it.
    np.testing.assert_allclose(w[:, 0], 0.7, rtol=1e-3)
    # The free rotation is about the feet's line (z = -0.3): the IMU then moves along y.
    np.testing.assert_allclose(v[:, 1], 0.7 * -0.3, rtol=1e-3)
    three = [*two, _point([0.0, 0.25, -0.3])]
    w3, _, seen3 = stance_twist(three, np.ones((5, 3)) / 3, fill)
    assert seen3.all()
    # The fill leaks in by FILL_WEIGHT over the feet's information on the rate about x (about 0.01
    # here: a third of the weight at 0.25 m from the line, squared): 1e-4 of 0.7.
    np.testing.assert_allclose(w3, 0.0, atol=1e-3)


def test_foot_plane_gives_the_tilt() -> None:
    """Four feet on level ground seen from a base rolled by 0.1 rad: gravity in the IMU frame."""
    feet = np.array([[0.2, 0.15, 0.0], [0.2, -0.15, 0.0], [-0.2, 0.15, 0.0], [-0.2, -0.15, 0.0]]) - [
        0,
        0,
        0.3,
    ]
    c, s = np.cos(0.1), np.sin(0.1)
    Rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # body -> world
    pts = feet @ Rx  # world points into the body frame: R^T p
    g = foot_plane_gravity(pts[None], np.ones((1, 4), bool), G)
    np.testing.assert_allclose(g[0], Rx.T @ G, atol=1e-9)
    assert np.isnan(foot_plane_gravity(pts[None], np.array([[True, True, False, False]]), G)).all()


def test_contact_threshold_from_swing_noise() -> None:
    """Bimodal forces with swing noise sigma 4: the threshold is mu + 3.09 sigma to the MAD's error
    (relative standard error about 1.1/sqrt(n) = 4 % for ~800 swing samples, 3 of them allowed)."""
    rng = np.random.default_rng(3)
    n = 2000
    down = (np.arange(n) % 250) < 150
    f = np.where(down, 250.0, 10.0) + rng.normal(0.0, 4.0, n)
    c = force_contacts(f[:, None], rate=100.0)
    assert c.k == pytest.approx(3.0902, abs=1e-3)
    assert c.threshold[0] == pytest.approx(10.0 + c.k * 4.0, abs=3 * 0.04 * c.k * 4.0 + 0.5)
    assert (c.down[:, 0] == down).mean() > 0.999


def test_transition_weights_and_ramp_time() -> None:
    down = np.zeros((100, 1), bool)
    down[40:80] = True
    w = transition_weights(down, rate=100.0, half_s=0.05)
    assert w[40, 0] == 0.0 and w[45, 0] == 1.0 and w[60, 0] == 1.0 and w[77, 0] == pytest.approx(0.6)
    f = np.where(down[:, 0], 100.0, 0.0)
    f[40:44] = [20.0, 40.0, 60.0, 80.0]
    c = force_contacts(f[:, None], rate=100.0, min_s=0.0)
    assert ramp_time(f[:, None], c, 100.0) == pytest.approx(0.02)


def test_linear_effect_recovers_a_known_coefficient_and_names_nothing_on_noise() -> None:
    rng = np.random.default_rng(7)
    X = rng.normal(size=(3000, 3, 2))
    block = np.arange(3000) // 100
    r = X @ np.array([0.3, -0.1]) + rng.normal(0.0, 0.2, (3000, 3))
    e = linear_effect("x", r, X, block)
    assert e["named"]
    for (lo, hi), true in zip(e["interval"], [0.3, -0.1], strict=True):
        assert lo <= true <= hi and hi - lo < 0.05
    null = linear_effect("x", rng.normal(0.0, 0.2, (3000, 3)), X, block)
    assert not null["named"] and null["gain"] < 0.005


def test_quantization_floor_matches_simulated_quantization() -> None:
    """White angle noise of a 2π/4096 quantum at 100 Hz, low-passed at 5 Hz and differentiated:
    the formula's gyro figure within 5 % (3 standard errors of a std from ~2,000 independent
    samples in the band)."""
    quantum, rate, fc = 2 * np.pi / 4096, 100.0, 5.0
    rng = np.random.default_rng(0)
    t = np.arange(20000) / rate
    x = lowpass(rng.uniform(-quantum / 2, quantum / 2, t.size), rate, fc)
    d1 = derivative(t, x)[100:-100].std()
    f = quantization_floor(quantum, rate, fc, 1.0, 1)
    assert d1 == pytest.approx(f["gyro_std"], rel=0.05)


def test_forward_select_names_the_present_effects_only() -> None:
    """Three candidate regressors, two in the residual: both named, the third not."""
    rng = np.random.default_rng(11)
    cands = {k: rng.normal(size=(3000, 3, 2)) for k in ("a", "b", "c")}
    r = cands["a"] @ np.array([0.4, 0.0]) + cands["c"] @ np.array([0.0, -0.2]) + rng.normal(0, 0.3, (3000, 3))
    named, rounds = forward_select(r, cands, np.arange(3000) // 100)
    assert sorted(named) == ["a", "c"] and len(rounds) == 3
