"""The fast estimator's tests: which joints move each IMU, from exact linear gyro models.

The public entry point is :func:`bodyschema.fast.fast_fit`; this module holds the settings, the result
and the tests on one grid, shared by the synced path and the timed one (:mod:`bodyschema.fast_timed`).

Why it works (docs/design.md, 'Science notes'):
a gyro on link ``g`` reads ``ω_g = R_gᵀ Σ_{j ∈ anc(g)} a_j q̇_j``. Between two
links joined by one hinge ``j`` (``g`` the child of ``h``) this collapses to a model that is *exact and
linear in a handful of features*::

    ω_g = A(q_j) ω_h + e q̇_j + b,      A(q) = B0 + B1 cos q + B2 sin q

because the relative rotation of the two links is a rotation about ``j``'s fixed axis (Rodrigues), and
the axis ``e`` seen from the child is constant. Gyro scale, cross-axis errors and mounting rotations are
linear maps and fold into ``B0..B2`` and ``e``; constant biases fold into ``b`` plus ``cos q_j``/``sin
q_j`` terms (the parent's bias, rotated). So for every pair of links and every joint, an ordinary
least-squares fit with 12 regressors either leaves only sensor noise (the right joint between
neighbouring links) or leaves the motion of at least one other joint (anything else). The tests are:

* **same link** (``ω_k = Q ω_m + b``): IMUs riding one rigid link are grouped (this replaces the
  paper's DPGMM merge for this method);
* **on the base** (``ω_k = b``): groups that do not rotate at all sit on a fixed base;
* **one hinge between** (the model above), for all ordered pairs of groups and all joints at once,
  with the Gram matrices batched over joints (one BLAS call per parent group);
* **two hinges between** (``ω_g = A_b(q_b)[A_a(q_a) ω_h + e_a q̇_a] + e_b q̇_b``) only for parts of the
  tree that the one-hinge test could not attach: a link without IMUs in between.

Each test compares the residual variance with what sensor noise alone would leave (noise estimated
from the data by the median absolute third difference, which removes smooth motion), so the decision is
a variance-ratio (F-type) test with threshold ``fit_ratio``. The accepted one-hinge edges form a
spanning forest (Kruskal, cheapest first, each joint used once) over the groups and the fixed world;
rooting it at the world orients it, and the joints crossed on the way from the world to a group
(symmetric difference along the path) are that group's ancestor set: its row of the dependency matrix
D. Joint-joint parents follow from D through the out-tree algebra (:mod:`bodyschema.estimate`).

Joints whose velocity the gyros cannot see above the noise (``min_excitation_snr``) are reported as
undetermined and left out of every test: their child link is then indistinguishable from their parent
link, and the answer is exact on the tree with those joints contracted. So are joints the tests could
not tell apart: acceptance alone is no decision, a rival model through another joint must fit
significantly worse (:func:`_rival_joints`; over a few seconds of slow motion the joints' rates are
nearly collinear and wrong models pass as well as right ones).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from scipy.sparse.csgraph import connected_components

from bodyschema.hinge import hinge_features

__all__ = [
    "PATH_SETTINGS",
    "FastFit",
    "FastOptions",
    "fast_options",
    "insufficient_excitation",
    "noise_level",
]

_WORLD = -1


def noise_level(x: np.ndarray) -> np.ndarray:
    """White-noise standard deviation per sensor from the median absolute third difference.

    ``x`` is (T, K, 3); returns (K,). The third difference of white noise has variance 20 σ², while
    smooth motion sampled fast enough nearly vanishes in it; the median ignores the few samples where
    a torque step makes the motion non-smooth.
    """
    if x.shape[0] < 8:
        return np.full(x.shape[1], np.nan)
    d3 = np.diff(x, n=3, axis=0)
    mad = np.median(np.abs(d3 - np.median(d3, axis=0)), axis=0)  # (K, 3)
    return np.sqrt(np.mean((1.4826 * mad) ** 2, axis=-1) / 20.0)


def insufficient_excitation(
    qd: np.ndarray, gyro: np.ndarray, min_excitation_snr: float = 15.0, min_excitation: float = 2e-3
) -> np.ndarray:
    """(N,) bool: joints whose RMS velocity the gyros cannot tell from noise.

    A joint is undetermined when its RMS velocity is below ``min_excitation_snr`` times the median gyro
    noise (then its two links move alike within noise) or below ``min_excitation`` rad/s.
    """
    sigma = noise_level(np.asarray(gyro, dtype=float))
    sigma_ref = float(np.median(sigma[np.isfinite(sigma)])) if np.isfinite(sigma).any() else 0.0
    excitation = np.sqrt(np.mean(np.asarray(qd, dtype=float) ** 2, axis=0))
    return excitation < max(min_excitation, min_excitation_snr * sigma_ref)


# ------------------------------------------------------------------------------------------ settings
@dataclass(frozen=True)
class FastOptions:
    """The fast estimator's settings, shared by :func:`fast_fit` and :class:`FastEstimator`.

    ``fit_ratio`` and the two excitation floors apply to both paths (:func:`fit_path`), ``rel_tol`` to
    the synced path only (the timed path has an error model instead,
    :func:`bodyschema.fast_timed.timed_fit`), the rest to the timed path only: :data:`PATH_SETTINGS`.
    """

    #: Residual variance over the noise-only expectation above which a model is rejected.
    fit_ratio: float = 25.0
    #: Synced data: relative model error allowed on top of sensor noise (scale nonlinearity, derived
    #: velocities), as a fraction of the signal RMS.
    rel_tol: float = 2e-3
    #: A joint is undetermined when its RMS velocity is below this many gyro noise standard deviations
    #: (the gyros could not tell its two links apart).
    min_excitation_snr: float = 15.0
    #: Absolute floor on that RMS velocity, rad/s.
    min_excitation: float = 2e-3
    #: Timed data: the IMU's on-chip low-pass bandwidth, Hz (None: not stated; the IMU Nyquist
    #: frequency is assumed, and :func:`fast_fit` reads it from the recording when it can).
    imu_bandwidth: float | None = None
    #: Timed data: the stated on-chip filter delay, s, taken out of the lag to report the clock skew
    #: (None: not stated; the recording's stated filter gives it, else 0).
    imu_delay: float | None = None
    #: Timed data: the comparison band, Hz (None: :func:`bodyschema.timing.choose_band` picks it).
    band: float | None = None
    #: Timed data: the largest lag of the IMU behind the encoders searched, s.
    max_lag: float = 0.1
    #: Timed data: the error model's relative model error before the lag and filter terms (the
    #: ``model_tol²`` in ``ε²``, :func:`bodyschema.fast_timed.timed_fit`).
    model_tol: float = 2e-3

    def __post_init__(self) -> None:
        # validated once, here: every entry point takes these options
        bad = [
            f"{f.name}={getattr(self, f.name)!r}"
            for f in fields(self)
            if (v := getattr(self, f.name)) is not None
            and not (v > 0 if f.name in ("fit_ratio", "imu_bandwidth", "band", "max_lag") else v >= 0)
        ]
        if bad:
            raise ValueError(
                f"FastOptions: {', '.join(bad)} out of range (ratios, rates and lags > 0, the rest >= 0)"
            )


_FIELDS = frozenset(f.name for f in fields(FastOptions))
_SHARED = frozenset({"fit_ratio", "min_excitation_snr", "min_excitation"})
#: The settings each path of :func:`fast_fit` uses (the one rule: a setting applies where it is listed).
PATH_SETTINGS: Mapping[str, frozenset[str]] = {
    "synced": _SHARED | {"rel_tol"},
    "timed": _FIELDS - {"rel_tol"},
}


def fast_options(options: FastOptions | None = None, **overrides: Any) -> FastOptions:
    """``options`` (default: the defaults) with the keywords ``overrides`` replacing its fields; a name
    that is no field is refused."""
    unknown = sorted(set(overrides) - _FIELDS)
    if unknown:
        raise TypeError(f"unexpected keyword argument(s) {unknown}; the settings are FastOptions fields")
    return replace(options or FastOptions(), **overrides)


@dataclass
class FastFit:
    """What :func:`fast_fit` learned (all arrays indexed like the inputs).

    ``dependency`` (K, N) bool is each IMU's ancestor set (all False for IMUs on the base);
    ``group`` (K,) the rigid link each IMU rides (-1 = the fixed base); ``undetermined`` joints the data
    cannot decide; ``imu_confidence`` (K,) and ``joint_confidence`` (N,) in [0, 1]; ``excitation``
    (N,) RMS joint velocity; ``edges`` the accepted (child group, parent group, joints) links, parent -1
    = world, with their variance ratios (two joints for an edge across a link without IMUs).
    """

    dependency: np.ndarray
    group: np.ndarray
    undetermined: np.ndarray
    imu_confidence: np.ndarray
    joint_confidence: np.ndarray
    excitation: np.ndarray
    noise: np.ndarray
    edges: list[tuple[int, int, tuple[int, ...], float]] = field(default_factory=list)
    #: The path taken (:func:`fit_path`); the settings stated but not used there (:data:`PATH_SETTINGS`).
    path: str = "synced"
    unused: tuple[str, ...] = ()
    #: Timed path only (:func:`bodyschema.fast_timed.timed_fit`): the IMU's lag behind the encoders
    #: at encoder-clock time ``lag_time`` s (the middle of the fit; clock skew plus filter delay), the
    #: skew alone (lag less the stated filter delay), the clock drift (the lag's slope; None from
    #: under 30 s of data, where there are not two 15 s segments to take a slope through), all as
    #: estimated, the lag's uncertainty (the segments' scatter about the drift line, at least
    #: :data:`~bodyschema.fast_timed.LAG_RESOLUTION`; None, like the drift, from under 30 s) and the
    #: comparison band.
    lag_ms: float | None = None
    lag_unc_ms: float | None = None
    lag_time: float | None = None
    skew_ms: float | None = None
    drift_ppm: float | None = None
    band_hz: float | None = None


# ----------------------------------------------------------------------------- least squares helpers
def _explained(F: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Sum of squares of centred ``Y`` (T, M) explained by regressors ``F`` (B, p, T) plus an intercept.

    Batched normal equations; ``F`` is centred algebraically (``FᵀF − T μμᵀ``; ``Y`` is already
    centred so ``FᵀY`` needs no correction), which saves a pass over the largest array. A ridge of 1e-9
    relative to each diagonal keeps (near) collinear columns finite without changing real fits.
    """
    B, p, T = F.shape
    mu = F.mean(axis=2)  # (B, p)
    G = F @ F.transpose(0, 2, 1) - T * mu[:, :, None] * mu[:, None, :]
    d = np.einsum("bii->bi", G)
    G = G + (1e-9 * d + 1e-300)[:, :, None] * np.eye(p)
    Bm = (F.reshape(B * p, T) @ Y).reshape(B, p, -1)  # one BLAS call for all batches
    X = np.linalg.solve(G, Bm)
    return np.sum(Bm * X, axis=1)


def _hop_features(wh: np.ndarray | None, c: np.ndarray, s: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Regressors (B, p, T) of the one-hinge model, batched over joints: ``c``, ``s``, ``qd`` (B, T).

    Rows: ``ω_h``, ``ω_h cos q``, ``ω_h sin q`` (when there is a parent gyro ``wh`` (3, T)), then
    ``cos q``, ``sin q`` (the parent's bias, rotated) and ``q̇``.
    """
    return hinge_features(wh, c, s, qd, ("cos", "sin", "qd"))


def _hop_features_banded(
    band: Callable[..., np.ndarray], wh: np.ndarray, c: np.ndarray, s: np.ndarray, joint_b: np.ndarray
) -> np.ndarray:
    """``band(_hop_features(wh, c, s, qd))`` with the rows shared by every joint (``ω_h``) and by every
    parent (``joint_b``: the banded ``cos q``, ``sin q``, ``q̇``, (B, 3, Tb)) filtered once by the
    caller: only the six products are filtered here. Same rows, same order."""
    B = c.shape[0]
    prod = np.empty((B, 6, c.shape[1]))
    np.multiply(wh, c[:, None, :], out=prod[:, 0:3])
    np.multiply(wh, s[:, None, :], out=prod[:, 3:6])
    prod_b = band(prod)
    F = np.empty((B, 12, prod_b.shape[-1]))
    F[:, 0:3] = band(wh)
    F[:, 3:9] = prod_b
    F[:, 9:12] = joint_b
    return F


def _two_hop_features(
    wh: np.ndarray | None,
    ca: np.ndarray,
    sa: np.ndarray,
    qda: np.ndarray,
    cb: np.ndarray,
    sb: np.ndarray,
    qdb: np.ndarray,
) -> np.ndarray:
    """Regressors (H, p, T) of ``ω_g = A_b(q_b)[A_a(q_a) ω_h + e_a q̇_a] + e_b q̇_b`` (+ rotated biases).

    ``wh`` is (H, 3, T) parent gyros (None for the fixed world, then H = 1); joint signals are (T,).
    """
    one = np.ones_like(ca)
    ta = np.stack([one, ca, sa])
    tb = np.stack([one, cb, sb])
    tab = (ta[:, None, :] * tb[None, :, :]).reshape(9, -1)
    rest = np.concatenate([tab[1:], qda[None] * tb, qdb[None]])  # (12, T)
    if wh is None:
        return rest[None]
    H, T = wh.shape[0], wh.shape[-1]
    F = np.empty((H, 27 + rest.shape[0], T))
    F[:, :27] = (wh[:, :, None, :] * tab[None, None]).reshape(H, 27, T)
    F[:, 27:] = rest
    return F


class _UnionFind:
    def __init__(self, n: int):
        self.p = list(range(n))

    def find(self, a: int) -> int:
        while self.p[a] != a:
            self.p[a] = self.p[self.p[a]]
            a = self.p[a]
        return a

    def union(self, a: int, b: int) -> bool:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        self.p[ra] = rb
        return True


@dataclass(frozen=True)
class _TimedTerms:
    """How timed data enter the tests (:func:`fast_fit_timed`); synced data have none of this.

    ``apply(x, axis)`` low-passes and picks the fit samples of every regressor and of the gyro alike,
    after the products are formed (the models stay exact); ``sigma`` (K,) is the in-band gyro noise
    per sample, ``floor_add`` (K,) the error model's other variance, ``rate_var`` (N,) what each
    joint's derived rate leaves per gyro channel in a model that uses it (the on-base and same-link
    tests, which compare gyros alone, carry the largest), ``n_eff`` the independent observations per
    fit sample, ``undetermined`` (N,) the joints the band cannot see.
    """

    apply: Callable[..., np.ndarray]
    sigma: np.ndarray
    floor_add: np.ndarray
    rate_var: np.ndarray
    n_eff: float
    undetermined: np.ndarray


def _identity(x: np.ndarray, axis: int = -1) -> np.ndarray:
    return x


@dataclass(frozen=True)
class _Signals:
    """The data as the tests see them. ``gyroT`` (K, 3, T) is unfiltered (products are formed first);
    ``gb`` the banded gyro, ``gc`` it centred, ``Tb`` its sample count; ``floor`` (K,) the variance a
    right model leaves besides the noise ``sigma``, and ``rate_var`` (Na,) what each active joint's
    derived rate adds to it in a model that uses that joint (zero on synced data); ``cos_q``,
    ``sin_q``, ``qda`` (T, Na) the signals of the ``active`` (determined) joints."""

    q: np.ndarray
    qd: np.ndarray
    band: Callable[..., np.ndarray]
    sigma: np.ndarray
    gyroT: np.ndarray
    gb: np.ndarray
    gc: np.ndarray
    Tb: int
    floor: np.ndarray
    rate_var: np.ndarray
    excitation: np.ndarray
    undetermined: np.ndarray
    active: np.ndarray
    n_eff: float
    cos_q: np.ndarray
    sin_q: np.ndarray
    qda: np.ndarray

    @property
    def n_obs(self) -> float:
        """Independent observations per output channel triple (the BIC's sample size)."""
        return 3 * self.Tb * self.n_eff


def _fit(
    q: np.ndarray, qd: np.ndarray, gyro: np.ndarray, opts: FastOptions, timed: _TimedTerms | None = None
) -> FastFit:
    """The tests on one grid (the module docstring): synced data, or timed data through ``timed``."""
    sig = _signals(*_checked(q, qd, gyro), opts, timed)
    # the gyro-only tests keep the largest derived-rate term: the median third difference reads a
    # low-passed gyro's in-band noise low (12 times on a 20 Hz DLPF), and this term covered it
    gyro_only = sig.floor + (float(sig.rate_var.max()) if sig.rate_var.size else 0.0)
    base_ratio = np.mean(sig.gc * sig.gc, axis=(0, 2)) / (sig.sigma**2 + gyro_only)
    grp = _same_link_groups(sig, base_ratio, opts.fit_ratio, gyro_only)
    ratio, s2 = _one_hinge_tests(sig, grp)
    uf, used, tree_edges = _spanning_forest(ratio, s2, grp.G, sig.n_obs, opts.fit_ratio)
    tree_edges += _two_hinge_edges(sig, grp, uf, used, opts.fit_ratio)
    nbrs, anc, parent_of = _orient(tree_edges, grp.G)
    edge_conf = _edge_confidence(sig, grp, s2, nbrs, parent_of, opts.fit_ratio)
    fit = _assemble(sig, grp, base_ratio, anc, parent_of, edge_conf, opts.fit_ratio)
    return _with_rivals(fit, sig, _rival_joints(ratio, nbrs, parent_of, sig, opts.fit_ratio))


#: Chance of calling one rival worse than the chosen model when it fits as well (split over the
#: rivals of a group, Bonferroni).
RIVAL_ALPHA = 1e-3


def _rival_joints(
    ratio: np.ndarray, nbrs: _Nbrs, parent_of: dict, sig: _Signals, fit_ratio: float
) -> set[int]:
    """Active joints whose place the data did not decide: a group attached through joints ``js``
    (variance ratio ``r``) while a one-hinge rival through another joint ``b`` fits about as well
    gives ``js`` and ``b``.

    The acceptance test (ratio under ``fit_ratio``) only rejects a model whose residual exceeds what
    the error model allows; between two models under it, only their residuals speak. A rival is
    rejected when its ratio ``r_b`` (both directions, as :func:`_spanning_forest` asks) exceeds the
    chosen one's by more than chance: ``r_b / r > F⁻¹(1 - α/m; ν_b, ν)``, the F quantile for the
    residual variances' own degrees of freedom ``ν = 3 n_eff (Tb - p - 1)`` (three channels, ``p``
    regressors each, ``n_eff`` independent values per fit sample), ``m`` rivals, ``α`` =
    :data:`RIVAL_ALPHA`. With the joints' rates independent a rival through the wrong joint leaves
    that joint's motion and fails by orders of magnitude; over a short stretch of slow motion the rates
    span a few smooth shapes (7 joints, 3 s of random excitation: singular values 1.1, 0.71, 0.11,
    0.04, 0.015, 0.003, 0.002 rad/s), the parent's gyro and the rotation terms mix them, and a model
    through the wrong joint fits about as well as the right one, better or worse: the joints
    are then undetermined, never guessed by BIC. Rivals through the same joint (the world model is
    nested in a sibling's) and the reversed edges of the group's own children (the same hinge) are no
    rivals; the BIC ranks those.
    """
    from scipy.stats import f as f_dist

    G = ratio.shape[0]
    world = G
    nu = {p: max(3.0 * sig.n_eff * (sig.Tb - p - 1), 1.0) for p in (1, 12, 40)}
    out: set[int] = set()
    for g, (h, js, r) in parent_of.items():
        both = ratio[g].copy()  # (G + 1, Na): g from h2 through b, and h2 from g
        both[:world] = np.maximum(both[:world], ratio[:, g, :])
        both[:, list(js)] = np.inf
        for y, yjs, _ in nbrs[g]:
            if parent_of.get(y, (None,))[0] == g and len(yjs) == 1:
                both[y, yjs[0]] = np.inf  # the reversed edge of a child of g: the same hinge
        m = max(int(np.isfinite(both).sum()), 1)
        nu_own = nu[1 if h == world else 12 if len(js) == 1 else 40]
        q = 1.0 - RIVAL_ALPHA / m
        bound = np.full(both.shape[0], f_dist.ppf(q, nu[12], nu_own))
        bound[world] = f_dist.ppf(q, nu[1], nu_own)
        close = (both < fit_ratio) & (both < max(r, 1e-12) * bound[:, None])
        rivals = np.flatnonzero(close.any(axis=0))
        if rivals.size:
            out |= set(js) | {int(b) for b in rivals}
    return out


def _with_rivals(fit: FastFit, sig: _Signals, rival: set[int]) -> FastFit:
    """``fit`` with the joints :func:`_rival_joints` found undetermined: their columns leave the
    dependency matrix's decided part (contracting a joint in a tree leaves a tree), their confidence
    is 0, and they are named as joints to move."""
    if not rival:
        return fit
    joints = sig.active[sorted(rival)]
    fit.undetermined = np.union1d(fit.undetermined, joints).astype(int)
    fit.joint_confidence[joints] = 0.0
    return fit


def _checked(q: np.ndarray, qd: np.ndarray, gyro: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``q``, ``qd``, ``gyro`` as float arrays, refused when their shapes disagree, they are too short
    or not finite."""
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    gyro = np.asarray(gyro, dtype=float)
    T, N = q.shape
    K = gyro.shape[1]
    if gyro.shape != (T, K, 3) or qd.shape != (T, N):
        raise ValueError(f"shapes do not agree: q {q.shape}, qd {qd.shape}, gyro {gyro.shape}")
    if T < 50:
        raise ValueError(f"need at least 50 samples to test models, got {T}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd)) and np.all(np.isfinite(gyro))):
        raise ValueError("q, qd and gyro must be finite")
    return q, qd, gyro


def _signals(
    q: np.ndarray, qd: np.ndarray, gyro: np.ndarray, opts: FastOptions, timed: _TimedTerms | None
) -> _Signals:
    """Noise, banded and centred gyro, error floor, excitation and the determined joints."""
    band = _identity if timed is None else timed.apply
    sigma = noise_level(gyro) if timed is None else timed.sigma
    sigma = np.where(np.isfinite(sigma), sigma, 0.0)
    gyroT = np.ascontiguousarray(gyro.transpose(1, 2, 0))  # (K, 3, T), unfiltered: products first
    gb = band(gyro, axis=0)
    gc = gb - gb.mean(axis=0)
    Tb = gc.shape[0]
    if Tb < 50:
        raise ValueError(f"need at least 50 samples to test models, got {Tb}")
    rms = np.sqrt(np.mean(gc * gc, axis=(0, 2)))  # (K,)
    rel_tol, floor_add = (opts.rel_tol, 0.0) if timed is None else (0.0, timed.floor_add)
    floor = (rel_tol * rms) ** 2 + floor_add + 1e-12

    qdb = band(qd, axis=0)
    excitation = np.sqrt(np.mean(qdb * qdb, axis=0))
    if timed is None:
        undetermined = insufficient_excitation(qd, gyro, opts.min_excitation_snr, opts.min_excitation)
    else:
        undetermined = timed.undetermined
    active = np.flatnonzero(~undetermined)
    rate_var = np.zeros(len(active)) if timed is None else np.asarray(timed.rate_var, dtype=float)[active]
    return _Signals(
        q=q,
        qd=qd,
        band=band,
        sigma=sigma,
        gyroT=gyroT,
        gb=gb,
        gc=gc,
        Tb=Tb,
        floor=floor,
        rate_var=rate_var,
        excitation=excitation,
        undetermined=undetermined,
        active=active,
        n_eff=1.0 if timed is None else timed.n_eff,
        cos_q=np.cos(q[:, active]),
        sin_q=np.sin(q[:, active]),
        qda=qd[:, active],
    )


@dataclass(frozen=True)
class _Groups:
    """IMUs grouped by the rigid link they ride: ``group`` (K,) (-1 = the fixed base), ``G`` groups,
    each with its ``members`` and a representative ``rep`` (the least noisy member), whose centred
    banded gyro ``Yg`` (Tb, 3G), energy ``ysq`` (G,) and noise ``sig_g`` (G,) stand for the group."""

    group: np.ndarray
    G: int
    members: list[np.ndarray]
    rep: np.ndarray
    member_conf: np.ndarray
    Yg: np.ndarray
    ysq: np.ndarray
    sig_g: np.ndarray


def _same_link_groups(sig: _Signals, base_ratio: np.ndarray, fit_ratio: float, floor: np.ndarray) -> _Groups:
    """The on-base test (``ω_k = b``: ``base_ratio`` below ``fit_ratio``) and the same-link test
    (``ω_k = Q ω_m + b``, IMU against IMU, with the error ``floor`` (K,)) group the IMUs by link."""
    gc, gb, Tb, sigma = sig.gc, sig.gb, sig.Tb, sig.sigma
    K = gc.shape[1]
    on_base = base_ratio < fit_ratio
    Fm = np.ascontiguousarray(gb.transpose(1, 2, 0))  # regress on one other IMU
    Y = gc.reshape(Tb, 3 * K)
    expl = _explained(Fm, Y).reshape(K, K, 3).sum(-1)  # [m, k]
    rss = np.sum(gc * gc, axis=(0, 2))[None, :] - expl
    dof = max(Tb - 4, 1)
    same = (rss / (3 * dof)) / (sigma[None, :] ** 2 + sigma[:, None] ** 2 + floor[None, :])  # [m, k]
    same = np.maximum(same, same.T)
    adj = (same < fit_ratio) & ~on_base[:, None] & ~on_base[None, :]
    _, comp = connected_components(adj, directed=False)
    moving = np.flatnonzero(~on_base)
    labels = sorted({int(comp[k]) for k in moving})
    gidx = {lab: i for i, lab in enumerate(labels)}
    group = np.array([-1 if on_base[k] else gidx[int(comp[k])] for k in range(K)])
    G = len(labels)
    members = [np.flatnonzero(group == g) for g in range(G)]
    rep = np.array([m[np.argmin(sigma[m])] for m in members], dtype=int)
    member_conf = np.ones(K)
    for m in members:
        if len(m) > 1:
            worst = np.max(same[np.ix_(m, m)], axis=1)
            member_conf[m] = np.clip(1.5 - worst / fit_ratio, 0.0, 1.0)
    Wg = gc[:, rep, :]  # (Tb, G, 3)
    return _Groups(
        group=group,
        G=G,
        members=members,
        rep=rep,
        member_conf=member_conf,
        Yg=Wg.reshape(Tb, 3 * G),
        ysq=np.sum(Wg * Wg, axis=(0, 2)),
        sig_g=sigma[rep],
    )


def _one_hinge_tests(sig: _Signals, grp: _Groups) -> tuple[np.ndarray, np.ndarray]:
    """The one-hinge model for all (child g, parent h, joint) at once; h == G is the fixed world.

    Returns the variance ratios and the residual variances per output, both (G, G + 1, Na), infinite
    where a group would be its own parent.
    """
    G, Na = grp.G, len(sig.active)
    cosT, sinT, qdT = (np.ascontiguousarray(x.T) for x in (sig.cos_q, sig.sin_q, sig.qda))
    ratio = np.full((G, G + 1, Na), np.inf)
    s2 = np.full((G, G + 1, Na), np.inf)  # residual variance per output
    if G and Na:
        sig_g, floor_g = grp.sig_g, sig.floor[grp.rep]
        # the band is linear and per channel: the rows that do not depend on the parent (cos q, sin q,
        # q̇) and the parent's own gyro are filtered once, only the products per (parent, joint)
        joint_b = sig.band(np.stack([cosT, sinT, qdT], axis=1))  # (Na, 3, Tb)
        for h in range(G + 1):
            if h == G:
                F = joint_b[:, 2:3]  # world: ω_g = e q̇_j + b
                exp_var = sig_g**2 + floor_g
            else:
                F = _hop_features_banded(sig.band, sig.gyroT[grp.rep[h]], cosT, sinT, joint_b)
                exp_var = sig_g**2 + sig_g[h] ** 2 + floor_g
            ex = _explained(F, grp.Yg).reshape(Na, G, 3).sum(-1)  # (Na, G)
            dof = max(sig.Tb - F.shape[1] - 1, 1)
            s2[:, h, :] = ((grp.ysq[None, :] - ex) / (3 * dof)).T
            ratio[:, h, :] = s2[:, h, :] / (exp_var[:, None] + sig.rate_var[None, :])
        for g in range(G):
            ratio[g, g, :] = np.inf
            s2[g, g, :] = np.inf
    return ratio, s2


_Edge = tuple[int, int, tuple[int, ...], float]  # (node, node, active joints, variance ratio)


def _spanning_forest(
    ratio: np.ndarray, s2: np.ndarray, G: int, n_obs: float, fit_ratio: float
) -> tuple[_UnionFind, set[int], list[_Edge]]:
    """Kruskal over the groups and the world (node G) from the accepted one-hinge edges, cheapest
    first, each joint used once. Returns the forest's components, the joints used and its edges."""
    world = G
    Na = ratio.shape[2]
    # Ordered by a BIC-type score: the world model (1 regressor) is nested in every one-hinge model
    # (12), so a child of the base fits below any of its siblings too; parsimony must pick the world.
    penalty = np.log(n_obs) / n_obs
    cand: list[tuple[float, float, int, int, int]] = []
    for g in range(G):
        for h in range(G + 1):
            if h != world and h < g:
                continue
            for a in range(Na):
                # a hinge explains both links exactly, each from the other; the easier direction alone
                # (a rank-deficient parent signal recovered from its child) can pass with a link missing
                # in between, so both directions must pass
                options = [(g, h)] if h == world else [(g, h), (h, g)]
                r = max(ratio[c, p, a] for c, p in options)
                if r < fit_ratio:
                    ls2 = max(np.log(max(s2[c, p, a], 1e-30)) for c, p in options)
                    score = ls2 + (1 if h == world else 12) * penalty
                    cand.append((float(score), float(r), g, h, a))
    cand.sort()
    uf = _UnionFind(G + 1)
    used: set[int] = set()
    tree_edges: list[_Edge] = []
    for _, r, g, h, a in cand:
        if a in used or uf.find(g) == uf.find(h):
            continue
        uf.union(g, h)
        used.add(a)
        tree_edges.append((g, h, (a,), r))
    return uf, used, tree_edges


def _two_hinge_edges(
    sig: _Signals, grp: _Groups, uf: _UnionFind, used: set[int], fit_ratio: float
) -> list[_Edge]:
    """Two-hinge edges that attach what the one-hinge forest left apart (a link without IMUs in
    between), cheapest first; ``uf`` is updated. The model from h to g crossing (a then b) is the model
    from g to h crossing (b then a); both directions must pass."""
    G, world = grp.G, grp.G
    spare = [a for a in range(len(sig.active)) if a not in used]
    if len(spare) < 2 or len({uf.find(x) for x in range(G + 1)}) <= 1:
        return []
    pairs = [(a, b) for a in spare for b in spare if a != b]
    pindex = {pq: i for i, pq in enumerate(pairs)}
    r2 = _two_hinge_ratios(sig, grp, pairs)
    cand2: list[tuple[float, int, int, tuple[int, int]]] = []
    for g in range(G):
        for h in range(G + 1):
            for i, (a, b) in enumerate(pairs):
                r = r2[g, h, i] if h == world else max(r2[g, h, i], r2[h, g, pindex[(b, a)]])
                if r < fit_ratio:
                    cand2.append((float(r), g, h, (a, b)))
    cand2.sort()
    edges: list[_Edge] = []
    for r, g, h, ab in cand2:
        if uf.find(g) != uf.find(h):
            uf.union(g, h)
            edges.append((g, h, ab, r))
    return edges


def _two_hinge_ratios(sig: _Signals, grp: _Groups, pairs: list[tuple[int, int]]) -> np.ndarray:
    """Variance ratios (G, G + 1, pairs) of the two-hinge model, batched like the one-hinge tests: per
    ordered joint pair, one solve for all parents and children."""
    G, world = grp.G, grp.G
    r2 = np.full((G, G + 1, len(pairs)), np.inf)
    wall = sig.gyroT[grp.rep]  # (G, 3, T)
    cos_q, sin_q, qda = sig.cos_q, sig.sin_q, sig.qda
    for i, (a, b) in enumerate(pairs):
        args = (cos_q[:, a], sin_q[:, a], qda[:, a], cos_q[:, b], sin_q[:, b], qda[:, b])
        for h_slice, wh in ((slice(0, G), wall), (slice(G, G + 1), None)):
            F = sig.band(_two_hop_features(wh, *args))
            ex = _explained(F, grp.Yg).reshape(F.shape[0], G, 3).sum(-1)  # (H, G)
            dof = max(sig.Tb - F.shape[1] - 1, 1)
            hs = np.arange(G + 1)[h_slice]
            par_var = np.where(hs == world, 0.0, grp.sig_g[hs % G] ** 2)[:, None]
            ev = grp.sig_g[None, :] ** 2 + sig.floor[grp.rep][None, :] + par_var + sig.rate_var[[a, b]].sum()
            r2[:, h_slice, i] = (((grp.ysq[None, :] - ex) / (3 * dof)) / ev).T
        for g in range(G):
            r2[g, g, i] = np.inf
    return r2


_Nbrs = dict[int, list[tuple[int, tuple[int, ...], float]]]


def _orient(
    tree_edges: list[_Edge], G: int
) -> tuple[_Nbrs, dict[int, frozenset[int]], dict[int, tuple[int, tuple[int, ...], float]]]:
    """Root the forest at the world (node G): each group's neighbours, ancestor set (the symmetric
    difference of the joints along its path from the world) and parent edge (parent, joints, ratio)."""
    world = G
    nbrs: _Nbrs = {x: [] for x in range(G + 1)}
    for g, h, js, r in tree_edges:
        nbrs[g].append((h, js, r))
        nbrs[h].append((g, js, r))
    anc: dict[int, frozenset[int]] = {world: frozenset()}
    parent_of: dict[int, tuple[int, tuple[int, ...], float]] = {}
    stack = [world]
    while stack:
        x = stack.pop()
        for y, js, r in nbrs[x]:
            if y not in anc:
                anc[y] = anc[x] ^ frozenset(js)
                parent_of[y] = (x, js, r)
                stack.append(y)
    return nbrs, anc, parent_of


def _edge_confidence(
    sig: _Signals,
    grp: _Groups,
    s2: np.ndarray,
    nbrs: _Nbrs,
    parent_of: dict[int, tuple[int, tuple[int, ...], float]],
    fit_ratio: float,
) -> np.ndarray:
    """Confidence (G,) in each group's attachment.

    BIC-type log likelihood ratio of the chosen attachment against the best rival one. Rivals are all
    other (parent, joint) models for this group except the reversed edges of its own tree children
    (those describe the same hinge). Nested rivals (a sibling's model around a base joint) pay their
    extra parameters, so they do not erode the confidence.
    """
    G, world = grp.G, grp.G
    sig_g, floor, rep = grp.sig_g, sig.floor, grp.rep
    n_obs = sig.n_obs
    edge_conf = np.zeros(G)
    half_log_n = 0.5 * np.log(n_obs)
    p2 = np.full((G + 1, 1), 12.0)  # every rival parent's one-hinge model, the world's one regressor
    p2[world] = 1.0
    for g in range(G):
        if g not in parent_of:
            continue
        h, js, r = parent_of[g]
        p_best = 1 if h == world else 12 if len(js) == 1 else 40
        own = sig_g[g] ** 2 + floor[rep[g]] + sig.rate_var[list(js)].sum()
        s2_best = max(r * (own + (0 if h == world else sig_g[h] ** 2)), 1e-30)
        rival = np.isfinite(s2[g])  # (G + 1, Na): every (parent, joint) but the chosen and the reversed
        if len(js) == 1:
            rival[h, js[0]] = False
        for y, yjs, _ in nbrs[g]:
            if y != h and len(yjs) == 1:
                rival[y, yjs[0]] = False
        ll = 0.5 * n_obs * (np.log(np.maximum(s2[g], 1e-30)) - np.log(s2_best))
        lam = float(np.min(ll + (p2 - p_best) * half_log_n, where=rival, initial=np.inf))
        fit_ok = 1.0 if r <= fit_ratio else fit_ratio / r
        edge_conf[g] = fit_ok / (1.0 + np.exp(-float(np.clip(lam, -50.0, 50.0))))
    return edge_conf


def _assemble(
    sig: _Signals,
    grp: _Groups,
    base_ratio: np.ndarray,
    anc: dict[int, frozenset[int]],
    parent_of: dict[int, tuple[int, tuple[int, ...], float]],
    edge_conf: np.ndarray,
    fit_ratio: float,
) -> FastFit:
    """The answer: each IMU's ancestor set (its row of D), the confidences and the accepted edges."""
    world, active = grp.G, sig.active
    K, N = len(grp.group), sig.q.shape[1]
    dep = np.zeros((K, N), dtype=bool)
    imu_conf = np.zeros(K)
    for k in range(K):
        g = grp.group[k]
        if g < 0:
            # a non-rotating IMU: confident in proportion to how clearly it does not rotate
            imu_conf[k] = float(np.clip(1.5 - base_ratio[k] / fit_ratio, 0.0, 1.0))
            continue
        if g in anc:
            for a in anc[g]:
                dep[k, active[a]] = True
            imu_conf[k] = min(edge_conf[g], grp.member_conf[k])
    joint_conf = np.zeros(N)
    child_of_joint: dict[int, int] = {}
    for g, (_, js, _) in parent_of.items():
        for a in js:  # both joints of a two-hinge edge: their order is the completion's business
            child_of_joint[a] = g
    for a in range(len(active)):
        g = child_of_joint.get(a)
        if g is None:
            continue
        h = parent_of[g][0]
        up = 1.0 if h == world else edge_conf[h]
        joint_conf[active[a]] = min(edge_conf[g], up)
    if sig.undetermined.any():
        # A joint seen still is a placeholder that could hang anywhere, and an IMU on its link (or a
        # joint under it) reads what one on the link above reads: every placement has that rival, so
        # none is decided while one is listed (bodyschema.verdict), and none is more than even odds.
        imu_conf = np.minimum(imu_conf, 0.5)
        joint_conf = np.minimum(joint_conf, 0.5)

    edges = [
        (g, (-1 if h == world else h), tuple(int(active[a]) for a in js), float(r))
        for g, (h, js, r) in parent_of.items()
    ]
    return FastFit(
        dependency=dep,
        group=grp.group,
        undetermined=np.flatnonzero(sig.undetermined),
        imu_confidence=imu_conf,
        joint_confidence=joint_conf,
        excitation=sig.excitation,
        noise=sig.sigma,
        edges=edges,
    )
