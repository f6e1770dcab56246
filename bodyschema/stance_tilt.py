"""The base's tilt that a flat stance foot fixes: an encoder offset or a turned IMU, from gravity.

A flat foot on level ground does not tilt, so while it stands the gravity the base IMU reads is the
foot's constant gravity turned by the leg's chain rotation, ``acc ≈ P(q) c`` with
``P(q) = exp([a_1] q_1) ... exp([a_J] q_J)`` (the product of exponentials of the stance chain's axes
at zero angles, as :mod:`bodyschema.stance_chains` fits them from the gyro) and ``c`` one constant
vector per leg (gravity in the foot, turned by the chain's zero pose), fitted on the baseline. The
residual's two components across gravity (radians of tilt, ``(acc - P c) / |c|`` projected on the
plane normal to the mean gravity) are what the checks read; along gravity nothing tilts.

**What a fault changes.** A 2 deg offset on joint ``j`` turns that leg's predicted gravity by 2 deg
about the joint's current axis, while its foot is down, and leaves every other leg's prediction as it
was; a 2 deg turn of the IMU on its mount turns the measured gravity, so every leg's residual moves by
the same tilt. The gyro sees the same faults only through ``0.035 |w|``, under the stance chain's
model error (``floating_health``); gravity sees them as ``g sin 2 deg = 0.34 m/s²`` on a constant.

**Error model.** What moves a stance leg's window-mean residual on a healthy robot is the base's own
acceleration (sway), the foot not lying flat (roll at touch-down, compliance of the sole and the
hip under load) and the gait changing over the window. None of these is white, so the spread comes
from the baseline itself: its stance samples are cut into blocks of ``block_s`` seconds (a stride or
more), each block's mean residual per leg is one draw, and the covariance of a window's mean over
``n`` blocks' worth of stance is the blocks' long-run covariance over ``n`` (lag covariances up to
``n`` blocks with Bartlett weights, Newey-West: neighbouring blocks of a gait are correlated, by 0.5
at one block on the iCub, which doubles a 10 s window's variance). The window's statistic is
Hotelling's ``T²`` against the ``F`` quantile at ``p_false`` (the covariance is itself estimated from
the baseline's ``G`` blocks). Beyond it, hypotheses are fitted
by generalised least squares to the window-mean residuals of all legs: the IMU turned (two tilt
angles, every leg alike) or one joint offset (one angle, that joint's leg only; its signature is the
model's own response to a small offset, computed on the window). The one whose residual is most
likely (chi-square survival at its degrees of freedom) names the finding. A rotation of the IMU
about gravity and an offset on a joint whose axis lies along gravity change no tilt: those stay
unseen here, which the finding list says by their absence.

Pure numpy/scipy; no URDF.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2
from scipy.stats import f as f_dist

from bodyschema.contacts import change_mask
from bodyschema.forward_kinematics import axis_rotations

__all__ = [
    "TiltLeg",
    "TiltModel",
    "TiltOptions",
    "chain_rotation",
    "tilt_hypotheses",
    "tilt_model",
    "tilt_test",
]


@dataclass(frozen=True)
class TiltOptions:
    """``block_s``: seconds of a baseline block (independent draws of the window mean; at least a
    stride). ``settle_s``: samples this close to any contact change are left out (a landing foot rolls).
    ``p_false``: chance per window of a false tilt finding. ``probe_rad``: the offset and turn the
    hypotheses' signatures are computed with (small: the response is linear)."""

    block_s: float = 2.0
    settle_s: float = 0.1
    p_false: float = 1e-3
    probe_rad: float = 0.01


@dataclass(frozen=True)
class TiltLeg:
    """One leg that stands on a flat foot: its force column, joint columns, chain axes and gravity."""

    foot: int
    columns: tuple[int, ...]
    axes: np.ndarray
    c: np.ndarray


@dataclass(frozen=True)
class TiltModel:
    """The legs, the tilt plane's basis (2, 3), and the baseline blocks' mean residuals (G, 2 L) with
    the stance samples each holds per leg (G, L)."""

    legs: tuple[TiltLeg, ...]
    basis: np.ndarray
    block_means: np.ndarray
    block_counts: np.ndarray

    def long_run_cov(self, blocks: float) -> np.ndarray:
        """Covariance (2 L, 2 L) of the mean of ``blocks`` consecutive blocks, times ``blocks``: the
        blocks' lag covariances up to the window's length (at most a quarter of the baseline's blocks)
        with Bartlett weights (Newey-West), since neighbouring blocks of a gait are not independent (a
        slow lean, the walking direction)."""
        X = self.block_means - self.block_means.mean(axis=0)
        G = X.shape[0]
        # lags beyond a quarter of the baseline's blocks are estimated from too few pairs (and, the
        # mean being removed, all lags together sum to nothing): the window stops there
        n = min(max(round(blocks), 1), max(G // 4, 1))
        S = X.T @ X / G
        for k in range(1, min(n, G)):
            g = X[k:].T @ X[:-k] / G
            S += (1.0 - k / n) * (g + g.T)
        return S


def chain_rotation(axes: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(T, 3, 3) ``exp([a_1] q_1) ... exp([a_J] q_J)``: the foot's rotation in the IMU frame up to the
    chain's constant zero pose, for unit-normalised ``axes`` (J, 3) and angles ``q`` (T, J)."""
    R = np.tile(np.eye(3), (q.shape[0], 1, 1))
    for j, a in enumerate(axes):
        R = R @ axis_rotations(a / max(float(np.linalg.norm(a)), 1e-12), q[:, j])
    return R


def _stance(down: np.ndarray, rate: float, opts: TiltOptions) -> np.ndarray:
    """(T, F) stance samples away from every contact change."""
    return down & ~change_mask(down, rate, opts.settle_s)[:, None]


def _residual(leg: TiltLeg, q: np.ndarray, acc: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(T, 2) tilt residual (rad) of ``acc`` (T, 3) against the leg's prediction at angles ``q``."""
    pred = np.einsum("tij,j->ti", chain_rotation(leg.axes, q[:, list(leg.columns)]), leg.c)
    return (acc - pred) @ basis.T / float(np.linalg.norm(leg.c))


def tilt_model(
    q: np.ndarray,
    acc: np.ndarray,
    down: np.ndarray,
    rate: float,
    chains: list[tuple[tuple[bool, ...], tuple[int, ...], np.ndarray]],
    opts: TiltOptions | None = None,
) -> TiltModel | None:
    """The tilt model of a healthy recording: ``q`` (T, N), ``acc`` (T, 3) of the base IMU, ``down``
    (T, F) contacts and the stance chains as (phase's feet down, columns, axes). Each chain's leg is
    the foot, among those down in its phase, whose stance its rotation explains best. None when no
    leg has two blocks of stance."""
    opts = opts or TiltOptions()
    stance = _stance(down, rate, opts)
    legs: list[TiltLeg] = []
    for key, cols, axes in chains:
        if any(leg.columns == cols for leg in legs):
            continue
        best = None
        for foot in np.flatnonzero(key):
            on = stance[:, foot]
            if on.sum() < 2 * opts.block_s * rate:
                continue
            P = chain_rotation(axes, q[on][:, list(cols)])
            c = np.einsum("tji,tj->i", P, acc[on]) / on.sum()
            rms = float(np.sqrt(np.mean((acc[on] - np.einsum("tij,j->ti", P, c)) ** 2)))
            if best is None or rms < best[0]:
                best = (rms, TiltLeg(int(foot), cols, axes, c))
        if best is not None and all(leg.foot != best[1].foot for leg in legs):
            legs.append(best[1])
    if not legs:
        return None
    g = np.mean([leg.c / np.linalg.norm(leg.c) for leg in legs], axis=0)
    basis = np.linalg.svd(np.eye(3) - np.outer(g, g) / float(g @ g))[2][:2]
    # (a unit basis of the plane across gravity: the two right singular vectors of the projector)
    means, counts = _block_means(TiltModel(tuple(legs), basis, np.zeros((0, 0)), np.zeros((0, 0))),
                                 q, acc, stance, rate, opts)  # fmt: skip
    ok = np.all(counts > 0, axis=1)
    if ok.sum() < 2 * len(legs) + 2:
        return None
    return TiltModel(tuple(legs), basis, means[ok], counts[ok])


def _block_means(
    model: TiltModel, q: np.ndarray, acc: np.ndarray, stance: np.ndarray, rate: float, opts: TiltOptions
) -> tuple[np.ndarray, np.ndarray]:
    """Per block of ``block_s``: each leg's mean residual over its stance samples (G, 2 L), and the
    samples (G, L)."""
    n = max(round(opts.block_s * rate), 1)
    G = q.shape[0] // n
    L = len(model.legs)
    means, counts = np.zeros((G, 2 * L)), np.zeros((G, L))
    for i, leg in enumerate(model.legs):
        r = _residual(leg, q, acc, model.basis)
        for b in range(G):
            on = stance[b * n : (b + 1) * n, leg.foot]
            counts[b, i] = on.sum()
            if on.any():
                means[b, 2 * i : 2 * i + 2] = r[b * n : (b + 1) * n][on].mean(axis=0)
    return means, counts


def _window_mean(
    model: TiltModel, q: np.ndarray, acc: np.ndarray, stance: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Every leg's mean residual over its stance samples (2 L,) and the samples per leg (L,)."""
    m, n = np.zeros(2 * len(model.legs)), np.zeros(len(model.legs))
    for i, leg in enumerate(model.legs):
        on = stance[:, leg.foot]
        n[i] = on.sum()
        if on.any():
            m[2 * i : 2 * i + 2] = _residual(leg, q[on], acc[on], model.basis).mean(axis=0)
    return m, n


def _window_cov(model: TiltModel, n: np.ndarray) -> np.ndarray:
    """Covariance of the window's mean residuals: the blocks' long-run covariance over the blocks'
    worth of stance the window holds, per pair of legs (the geometric mean of their counts)."""
    per_block = model.block_counts.mean(axis=0)  # stance samples per block, per leg
    blocks = np.maximum(n, 1.0) / np.maximum(per_block, 1.0)
    k = np.repeat(blocks, 2)
    return model.long_run_cov(float(blocks.mean())) / np.sqrt(np.outer(k, k))


def tilt_test(
    model: TiltModel, q: np.ndarray, acc: np.ndarray, down: np.ndarray, rate: float, opts: TiltOptions
) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray] | None:
    """``(T², critical value, window-mean residual, its covariance, stance mask)`` of one window;
    None when a leg has no stance in it."""
    stance = _stance(down, rate, opts)
    m, n = _window_mean(model, q, acc, stance)
    if np.any(n < 1):
        return None
    S = _window_cov(model, n)
    t2 = float(m @ np.linalg.pinv(S) @ m)
    G, k = model.block_means.shape
    # Hotelling's T² of one new draw against G blocks' mean and covariance
    crit = (1 + 1 / G) * k * (G - 1) / max(G - k, 1) * float(f_dist.isf(opts.p_false, k, max(G - k, 1)))
    return t2, crit, m, S, stance


def tilt_hypotheses(
    model: TiltModel,
    q: np.ndarray,
    acc: np.ndarray,
    stance: np.ndarray,
    m: np.ndarray,
    S: np.ndarray,
    opts: TiltOptions,
) -> list[tuple[str, str, int, float, float]]:
    """``(kind, description, part, angle in deg, likelihood)`` of each hypothesis, most likely first:
    ``imu`` (part -1, the turn's size) and ``offset`` on each chain joint (part: its column). The
    likelihood is the chi-square survival of the GLS residual at its degrees of freedom."""
    W = np.linalg.pinv(S)
    k = m.size
    out = []

    def fit(H: np.ndarray) -> tuple[np.ndarray, float]:
        x = np.linalg.lstsq(H.T @ W @ H, H.T @ W @ m, rcond=None)[0]
        e = m - H @ x
        return x, float(chi2.sf(float(e @ W @ e), max(k - H.shape[1], 1)))

    base, _ = _window_mean(model, q, acc, stance)
    H = np.zeros((k, 2))
    for a in range(2):
        R = axis_rotations(model.basis[a], np.array([opts.probe_rad]))[0]
        H[:, a] = (_window_mean(model, q, acc @ R.T, stance)[0] - base) / opts.probe_rad
    x, p = fit(H)
    turn = float(np.degrees(np.linalg.norm(x)))
    out.append(("imu", f"turned {turn:.1f} deg", -1, turn, p))
    for leg in model.legs:
        for c in leg.columns:
            qq = q.copy()
            qq[:, c] += opts.probe_rad
            h = (_window_mean(model, qq, acc, stance)[0] - base) / opts.probe_rad
            if np.linalg.norm(h) < 1e-3:
                continue
            x, p = fit(h[:, None])
            out.append(("offset", f"offset {np.degrees(x[0]):+.1f} deg", c, float(np.degrees(x[0])), p))
    return sorted(out, key=lambda h: -h[4])
