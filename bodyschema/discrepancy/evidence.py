"""Evidence for each error effect on each channel: a test that holds for autocorrelated residuals.

Why not the residual energy it removes, or an ordinary least-squares test: the residual of a real IMU
against its reference is far from white (unmodelled motion-capture jitter, filter differences,
slow drifts), so its samples are not independent and an ordinary test calls everything significant;
and a gain counted over both channels lets the accelerometer's larger residual hide a small gyro
effect. Here every effect is tested on each channel it touches, on its own:

1. The effect's signature on the channel is its columns of the model Jacobian at the current fit
   (:func:`bodyschema.discrepancy.fit.jacobian`); the columns of the effects already in the model are
   projected out of both the signature and the residual (Frisch-Waugh), so the test asks what the
   effect adds to the model, not what it shares with it.
2. The residual is regressed on the remaining signature: the estimate is the parameter change the
   channel asks for, in the effect's own units.
3. Its covariance is cluster-robust over contiguous time blocks (``block_s`` seconds, the sandwich
   ``(X'X)^-1 (sum_b X_b' u_b u_b' X_b) (X'X)^-1``, scaled by ``G/(G-1)``): any correlation within a
   block is allowed, only the blocks are taken as independent. The Wald statistic is referred to an
   F distribution with ``(k, G-k)`` degrees of freedom (``G`` blocks, ``k`` parameters), the usual
   small-sample form for few clusters.
4. The **detection limit** at level ``alpha``: the smallest change of the effect, in its weakest
   direction, whose Wald statistic reaches the critical value (so it is named about half the time;
   three times it is named almost always). It scales with the channel's residual, the amount of
   motion that excites the signature and the recording's length, so it differs per recording.

Example: a gyro bias of 0.02 rad/s in white noise of 0.01 rad/s on 60 s of rotation is found with its
value and a detection limit well below it; the accelerometer, which the bias does not touch, is not
tested for it.

>>> import numpy as np
>>> from bodyschema.discrepancy.fit import prepare
>>> from bodyschema.rigid_motion import reference_motion, smooth_random_motion
>>> rng = np.random.default_rng(1)
>>> m = smooth_random_motion(60.0, 100.0, rng)
>>> ref = reference_motion(m["t"], m["quat"], m["pos"], cutoff=None)
>>> gyro = m["gyro"] + [0.02, 0.0, 0.0] + rng.normal(0.0, 0.01, m["gyro"].shape)
>>> prob = prepare(ref, gyro, m["acc"] + rng.normal(0.0, 0.05, m["acc"].shape), cutoff=None)
>>> (ev,) = effect_evidence(prob, {}, [], ["gyro_bias"])
>>> ev.channel, round(ev.estimate[0], 3), ev.p_value < 1e-6, ev.detection_limit < 0.005
('gyro', 0.02, True, True)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import f as f_dist

from bodyschema.discrepancy.effects import EFFECTS, nominal, pack
from bodyschema.discrepancy.fit import Problem, jacobian, residual

__all__ = ["CHANNELS", "Evidence", "critical_wald", "effect_evidence", "n_clusters", "signatures", "wald"]

#: The residual columns of each channel (gyro xyz, then accelerometer xyz); ``both`` stacks them (the
#: evidence of a named effect that moves both, such as a time offset).
CHANNELS: dict[str, slice] = {"gyro": slice(0, 3), "acc": slice(3, 6), "both": slice(0, 6)}


@dataclass(frozen=True)
class Evidence:
    """One effect tested on one channel, given the effects already in the model.

    ``estimate``/``stderr``: the parameter change the channel asks for and its cluster-robust standard
    error (the effect's units: s, rad/s, m/s², gain, rad, m); ``p_value``: of the Wald F test that the
    change is zero; ``detection_limit``: the smallest change (vector norm, the effect's units) this
    channel of this recording reveals at level ``alpha``; ``clusters``: the time blocks.
    """

    effect: str
    channel: str
    estimate: tuple[float, ...]
    stderr: tuple[float, ...]
    statistic: float
    p_value: float
    detection_limit: float
    clusters: int
    alpha: float

    @property
    def magnitude(self) -> float:
        """Norm of the estimated change (comparable with :attr:`detection_limit`)."""
        return float(np.linalg.norm(self.estimate))

    def to_json(self) -> dict[str, object]:
        return {
            "effect": self.effect,
            "channel": self.channel,
            "estimate": [float(f"{x:.6g}") for x in self.estimate],
            "stderr": [float(f"{x:.3g}") for x in self.stderr],
            "statistic": round(self.statistic, 3),
            "p_value": float(f"{self.p_value:.3g}"),
            "detection_limit": float(f"{self.detection_limit:.3g}"),
            "clusters": self.clusters,
            "alpha": self.alpha,
        }


def _columns(names: Sequence[str]) -> dict[str, np.ndarray]:
    """Each effect's column indices in a Jacobian over ``names`` in library order."""
    cols = [n for n in EFFECTS if n in names]
    offs = np.cumsum([0] + [EFFECTS[n].size for n in cols])
    return {n: np.arange(offs[i], offs[i + 1]) for i, n in enumerate(cols)}


def effect_evidence(
    prob: Problem,
    params: Mapping[str, Mapping[str, object]],
    model: Sequence[str],
    candidates: Sequence[str],
    *,
    alpha: float = 0.01,
    block_s: float = 2.0,
    min_gain: float = 0.0,
    energy_floor: tuple[float, float] = (0.0, 0.0),
    channels: Sequence[str] = ("gyro", "acc"),
) -> list[Evidence]:
    """Test every effect of ``candidates`` on every channel it touches, given the effects ``model``.

    ``params``: the current fit (of ``model``). A candidate that is itself in ``model`` is tested
    given the others, with its own fitted contribution added back to the residual (linearised), so
    its estimate is its fitted change from null and the test its evidence in the final model.
    ``alpha``: the family level; the detection limits refer to it split over the single-channel
    tests made (Bonferroni), the level at which the selection names an effect. ``min_gain``: the
    least share of what the model leaves of the channel's residual energy (at least
    ``energy_floor``, gyro and acc, in the normalised units) an effect must explain to be named; the
    detection limit is also at least the change that explains that much. ``block_s``: the length of
    the time blocks taken as independent. ``channels``: of :data:`CHANNELS`. Returns one
    :class:`Evidence` per effect and channel, in library order; a channel the effect does not move (a
    gyro bias on the accelerometer) is left out.
    """
    idx = prob.index
    names = [n for n in EFFECTS if n in set(model) | set(candidates)]
    J, base, cols = signatures(prob, params, names)
    n_blocks = n_clusters(prob, block_s)
    blocks = np.array_split(np.arange(idx.size), n_blocks)
    cases = []
    for ch in channels:
        sl = CHANNELS[ch]
        rows = sl.stop - sl.start
        y_all = base[idx, sl].reshape(-1)
        Jc = J[idx, sl, :].reshape(idx.size * rows, -1)
        for c in (n for n in names if n in candidates):
            X = Jc[:, cols[c]]
            if not _moves(X, rows):
                continue
            y = y_all
            if c in model:
                y = y + X @ (pack(params, [c], prob.ref) - nominal(c, prob.ref))
            floor = float(np.mean(np.asarray(energy_floor)[[i // 3 for i in range(sl.start, sl.stop, 3)]]))
            least = min_gain * max(float(np.mean(y**2)), floor)
            others = [n for n in names if n in model and n != c]
            if others:
                q, _ = np.linalg.qr(Jc[:, np.concatenate([cols[n] for n in others])])
                y = y - q @ (q.T @ y)
                X = X - q @ (q.T @ X)
            cases.append((c, ch, X, y, rows, least))
    level = alpha / max(1, sum(ch != "both" for _, ch, *_ in cases))
    out = [wald(c, ch, X, y, rows, blocks, level, least) for c, ch, X, y, rows, least in cases]
    order = {n: i for i, n in enumerate(EFFECTS)}
    return sorted(out, key=lambda e: (order[e.effect], list(CHANNELS).index(e.channel)))


def signatures(
    prob: Problem, params: Mapping[str, Mapping[str, object]], names: Sequence[str]
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """``(columns (T, 6, p), base residual (T, 6), each effect's column indices)`` of the effects
    ``names`` around ``params``: the model Jacobian, with the time offset's column taken from the
    model's derivative (:func:`_offset_signature`)."""
    names = [n for n in EFFECTS if n in names]
    J, base = jacobian(prob, params, names)
    cols = _columns(names)
    if "time_offset" in cols:
        J[:, :, cols["time_offset"][0]] = _offset_signature(prob, params)
    return J, base, cols


def n_clusters(prob: Problem, block_s: float) -> int:
    """The number of time blocks the evidence tests take as independent."""
    return max(2, round(prob.index.size / prob.rate / block_s))


def critical_wald(level: float, k: int, clusters: int) -> float:
    """The Wald statistic a ``k``-parameter change must reach at ``level`` with ``clusters`` blocks
    (the F form of :func:`wald`): a detection limit is ``sqrt`` of it standard errors."""
    dof = max(clusters - k, 1)
    return float(f_dist.isf(level, k, dof)) * k * max(clusters - 1, 1) / dof


def _offset_signature(prob: Problem, params: Mapping[str, Mapping[str, object]]) -> np.ndarray:
    """(T, 6) the time offset's signature from the model: minus the time derivative of the prediction.

    The fit applies the offset to the measurement (:meth:`~bodyschema.discrepancy.fit.Problem.
    measured`), so its finite-difference column is the derivative of the *measured* reading, noise
    included; regressing the residual, which is that noise, on it finds an offset in pure white noise
    (every seed of a 1,000-seed null sweep). The model's derivative carries the same signature
    without the noise.
    """
    _, pred = residual(prob, {k: v for k, v in params.items() if k != "time_offset"})
    sig = -np.gradient(pred, prob.ref.t, axis=0)
    sig[:, :3] /= prob.scale[0]
    sig[:, 3:] /= prob.scale[1]
    return sig


def _moves(X: np.ndarray, rows: int) -> bool:
    """Whether the signature moves every channel stacked in ``X`` (a stacked test of an effect that
    moves only one channel would repeat that channel's)."""
    X3 = X.reshape(-1, rows, X.shape[1])
    return all(np.sqrt(np.mean(X3[:, i : i + 3] ** 2)) > 1e-9 for i in range(0, rows, 3))


def wald(
    effect: str,
    channel: str,
    X: np.ndarray,
    y: np.ndarray,
    rows: int,
    blocks: list[np.ndarray],
    alpha: float,
    least_energy: float,
) -> Evidence:
    """Regression of ``y`` on ``X`` (``rows`` rows per sample) with the block-robust Wald F test.

    The detection limit is the larger of the change the test reveals at ``alpha`` and the change that
    explains ``least_energy`` (mean squared normalised residual), both in the weakest direction."""
    k = X.shape[1]
    G = len(blocks)
    inv = np.linalg.pinv(X.T @ X)
    b = inv @ (X.T @ y)
    u = y - X @ b
    X3 = X.reshape(-1, rows, k)
    u3 = u.reshape(-1, rows)
    scores = np.stack([np.einsum("tck,tc->k", X3[g], u3[g]) for g in blocks])
    V = inv @ (scores.T @ scores) @ inv * G / max(G - 1, 1)
    dof = max(G - k, 1)
    W = float(b @ np.linalg.pinv(V) @ b)
    F = W * dof / (k * max(G - 1, 1))
    p = float(f_dist.sf(F, k, dof))
    w_crit = critical_wald(alpha, k, G)
    limit = float(np.sqrt(w_crit * max(float(np.linalg.eigvalsh(V)[-1]), 0.0)))
    weakest = max(float(np.linalg.eigvalsh(X.T @ X)[0]), 1e-300)
    limit = max(limit, float(np.sqrt(least_energy * X.shape[0] / weakest)))
    se = np.sqrt(np.clip(np.diag(V), 0.0, None))
    return Evidence(
        effect, channel, tuple(float(x) for x in b), tuple(float(x) for x in se), W, p, limit, G, alpha
    )
