"""Effects of a walking robot's body that the IMU effect library has no word for, tested held out.

After :mod:`bodyschema.discrepancy` has fitted what the IMU itself gets wrong, what is left of the
residual may follow the robot's body:

* ``leg_compliance``: a joint that flexes under load (the iCub's hip roll): its angle is off by
  ``c F`` with ``F`` the leg's vertical load, so a flat stance foot's prediction of the base rate is
  off by ``-a c dF/dt`` (``a`` the joint's axis in the IMU frame, weighted by the foot's stance
  share), and its specific force by ``w (c d²F/dt² (a x p_j) - c F (a x g))`` (the base turned by
  ``-c F`` about the joint's axis through ``p_j``); one ``c`` (rad/N) per leg. A sole that turns
  under the moment ``M`` of the ground's reaction is the same terms with ``M`` for ``F`` and the
  sole's axis through its origin (rad/(N m));
* ``acc_delay``: the accelerometer alone lags the model by ``tau`` beyond the common time offset
  (an accelerometer held at half the log's rate lags by half its update period): residual
  ``-tau d(acc)/dt``;
* ``contact_transition``: the residual near contact changes (lift-off, touch-down: the foot rolls or
  slips, which a rigid flat or point foot does not) against the rest, as an RMS ratio.

Each linear effect is fitted by least squares, its 95 % interval from the block-robust covariance
(time blocks independent, samples within one not: the IMU analysis's rule), its significance by a
Wald test, and its gain held out: fitted on all blocks but one and scored on that one, in turn.

>>> import numpy as np
>>> rng = np.random.default_rng(1)
>>> X = rng.normal(size=(2000, 3, 1)); r = 0.5 * X[..., 0] + rng.normal(0, 0.1, (2000, 3))
>>> e = linear_effect("x", r, X, np.arange(2000) // 100)
>>> round(e["value"][0], 2), e["gain"] > 0.9
(0.5, True)
"""

from __future__ import annotations

import numpy as np
from scipy.stats import f as f_dist
from scipy.stats import t as t_dist

__all__ = ["forward_select", "linear_effect", "transition_ratio"]


def _fit(r: np.ndarray, X: np.ndarray) -> np.ndarray:
    A = X.reshape(-1, X.shape[-1])
    return np.linalg.lstsq(A, r.reshape(-1), rcond=None)[0]


def linear_effect(
    name: str,
    resid: np.ndarray,
    X: np.ndarray,
    block: np.ndarray,
    alpha: float = 0.01,
    min_gain: float = 0.005,
) -> dict[str, object]:
    """The effect ``resid (T, 3) ~ X (T, 3, k) @ c``: value, standard error, 95 % interval, Wald p,
    held-out gain over the distinct values of ``block`` (T,), and whether it is named (p below
    ``alpha`` and held-out gain at least ``min_gain`` of the residual energy)."""
    k = X.shape[-1]
    beta = _fit(resid, X)
    groups = np.unique(block)
    G = groups.size
    A = X.reshape(-1, k)
    bread = np.linalg.pinv(A.T @ A)
    meat = np.zeros((k, k))
    e = resid - X @ beta
    for g in groups:
        m = block == g
        s = np.einsum("tik,ti->k", X[m], e[m])
        meat += np.outer(s, s)
    cov = bread @ meat @ bread * G / max(G - 1, 1)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    q = float(t_dist.ppf(0.975, max(G - 1, 1)))
    wald = float(beta @ np.linalg.pinv(cov) @ beta) / k
    p = float(f_dist.sf(wald, k, max(G - k, 1)))
    before, after = np.zeros(resid.shape[1]), np.zeros(resid.shape[1])
    for g in groups:
        test = block == g
        b = _fit(resid[~test], X[~test])
        before += np.sum(resid[test] ** 2, axis=0)
        after += np.sum((resid[test] - X[test] @ b) ** 2, axis=0)
    gain = 1.0 - after.sum() / before.sum() if before.sum() > 0 else 0.0
    return {
        "effect": name,
        "value": beta.tolist(),
        "std": se.tolist(),
        "interval": [[float(b - q * s), float(b + q * s)] for b, s in zip(beta, se, strict=True)],
        "p_value": p,
        "gain": float(gain),
        "held_out_energy": {"before": before.tolist(), "after": after.tolist()},
        "blocks": int(G),
        "named": bool(p < alpha and gain >= min_gain),
    }


def transition_ratio(resid: np.ndarray, near: np.ndarray, block: np.ndarray) -> dict[str, object]:
    """RMS of ``resid`` (T, 3) on the samples ``near`` contact changes against the rest, with a 95 %
    interval of the ratio from the delete-one-block jackknife."""

    def ratio(keep: np.ndarray) -> float:
        a, b = resid[keep & near], resid[keep & ~near]
        return float(np.sqrt(np.mean(a**2) / np.mean(b**2))) if a.size and b.size else np.nan

    groups = np.unique(block)
    full = ratio(np.ones(len(block), bool))
    jack = np.array([ratio(block != g) for g in groups])
    jack = jack[np.isfinite(jack)]
    G = jack.size
    se = float(np.sqrt((G - 1) / G * np.sum((jack - jack.mean()) ** 2))) if G > 1 else float("nan")
    q = float(t_dist.ppf(0.975, max(G - 1, 1)))
    return {
        "effect": "contact_transition",
        "rms_near": float(np.sqrt(np.mean(resid[near] ** 2))) if near.any() else None,
        "rms_far": float(np.sqrt(np.mean(resid[~near] ** 2))) if (~near).any() else None,
        "ratio": full,
        "interval": [full - q * se, full + q * se],
        "near_fraction": float(near.mean()),
        "named": bool(np.isfinite(se) and full - q * se > 1.0),
    }


def forward_select(
    resid: np.ndarray,
    candidates: dict[str, np.ndarray],
    block: np.ndarray,
    alpha: float = 0.01,
    min_gain: float = 0.005,
) -> tuple[list[str], list[dict[str, object]]]:
    """Name candidate linear effects one at a time: each round tests every candidate not yet named,
    its regressors and the residual with the named ones projected out (Frisch-Waugh), at ``alpha``
    split over the round's tests (Bonferroni); the most significant one that also gains
    ``min_gain`` held out joins. Returns the names in order and each round's tests."""
    named: list[str] = []
    rounds: list[dict[str, object]] = []
    while len(named) < len(candidates):
        base = np.concatenate([candidates[n] for n in named], axis=2) if named else None
        r = resid if base is None else resid - base @ _fit(resid, base)
        tests = {}
        for name, X in candidates.items():
            if name in named:
                continue
            Xp = X
            if base is not None:
                A = base.reshape(-1, base.shape[-1])
                coef = np.linalg.lstsq(A, X.reshape(-1, X.shape[-1]), rcond=None)[0]
                Xp = X - base @ coef
            tests[name] = linear_effect(
                name, r, Xp, block, alpha / max(len(candidates) - len(named), 1), min_gain
            )
        rounds.append({n: {"p_value": e["p_value"], "gain": e["gain"]} for n, e in tests.items()})
        ok = [n for n, e in tests.items() if e["named"]]
        if not ok:
            break
        named.append(min(ok, key=lambda n: tests[n]["p_value"]))
    return named, rounds
