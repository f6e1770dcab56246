"""Held-out runner-up tests for a tree the sensor networks chose: a part is decided only when every
rival answer predicts the held-out gyro significantly worse than the chosen one.

The networks' Jacobian ranks answers; it does not say how sure a ranking is. Two joints driven alike
(one phase, or a jammed joint that hardly moves) give the networks a best tree that can be wrong by
a hair, and the dependency threshold has no error model to tell. So every part of the chosen tree is
checked against its rivals with the exact gyro models of :mod:`bodyschema.fast_core` (docs/design.md,
'Science notes'), fitted on one half of the window and scored on the other (two folds):

* **IMU k on joint J** (the chosen answer) predicts k's gyro from the nearest other IMU up the chosen
  tree through the hinges crossed (``ω_k = A(q_J) ω_h + e q̇_J + b``; two hinges across a link
  without another IMU; ``ω_k = e q̇_J + b`` from the base). Rivals: k on every other joint under
  every parent, and on the base. A rival joint hung under a joint of its own subtree is a tree only
  if the IMUs its model reads above it leave its link for the link it hung from; it stays a rival
  only where they fit there.
* **joint J under P**: the IMUs on J's link predicted from P's link through J. Rivals: J under every
  joint outside its own subtree, and under the base.

Error model (per output channel of IMU k, predicted from IMU h; both in the comparison band ``fc`` of
:func:`bodyschema.timing.choose_band`): ``v = σ_k² + σ_h² + Σ_hinges σ_q̇² + ε² RMS_k²`` with ``σ`` the
in-band gyro noise (:func:`bodyschema.timing.gyro_band_noise`, through the stated low-pass), ``σ_q̇`` the
in-band derivative noise of the encoder positions (:func:`bodyschema.timing.derivative_noise`), summed over
the hinges the model reads, and ``ε² = model_tol² + (2π f_rms δ)²`` the relative model error of a velocity
derived from 100 Hz positions and of the lag's uncertainty ``δ`` (the fast fit's measured one where it
aligned the streams: ``timing["lag_unc_ms"]``). A model *fits* when its held-out residual variance is below
``fit_ratio · v`` (the fast method's variance-ratio test, same ratio). A part is decided when its chosen
model fits and every rival that fits leaves significantly more held-out residual, beyond chance (the F
quantile of the fast method's rival test) and beyond what the model error could leave
(:func:`_close_rivals`); otherwise it is undetermined, with the joints whose motion would tell the answers
apart (the joints on one answer's path and not on the other's). A joint whose in-band motion leaves less
than ``fit_ratio · v`` of residual when left out cannot be resolved at all and is reported as insufficient
excitation.

Confidence of a decided part: ``1 / (1 + exp(-Λ))`` with ``Λ = ½ n (log s²_rival − log s²_chosen)``
the log-likelihood ratio of the best rival on the ``n`` independent held-out values (the band keeps
``2 fc`` per second and channel); an undetermined part gets ``1 / (1 + rivals that fit)`` (at most ½),
and 0 when its chosen model does not fit.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from bodyschema.fast_core import RIVAL_ALPHA, FastOptions, _hop_features, _two_hop_features
from bodyschema.fast_timed import stated_filter
from bodyschema.recording import Recording
from bodyschema.topology import Topology

__all__ = ["HeldOutOptions", "HeldOutPart", "HeldOutTest", "heldout_check", "heldout_test"]

_WORLD = -1
#: Least excess of a rejected rival's held-out ratio over the chosen answer's, in error-model
#: variances: what the stated model error could leave between two answers (:func:`_close_rivals`).
RIVAL_MARGIN = 1.0


@dataclass(frozen=True)
class HeldOutOptions:
    """Settings of the held-out runner-up tests (defaults: the fast method's timed path)."""

    #: Held-out residual variance over the error model's above which a model does not fit.
    fit_ratio: float = 25.0
    #: The error model's relative model error before the lag term.
    model_tol: float = 2e-3
    #: Uncertainty of the IMU-to-encoder lag the streams were aligned by, s.
    lag_unc: float = 1e-3
    #: Comparison band, Hz (None: :func:`bodyschema.timing.choose_band` from the rate and the stated
    #: IMU filter).
    band: float | None = None
    #: Largest relative gain error of a hinge between two gyros: each MPU-6050 gyro may be off by ±3 % in
    #: scale and ±2 % cross-axis (docs/design.md, 'Facts the error models use'), so a fitted hinge axis ``e``
    #: and the parent's rotation ``A(q)`` have unit gain within 10 %, plus four standard errors of the fit.
    gain_tol: float = 0.1
    #: At most this many rival trees are kept as the answer's candidates.
    max_candidates: int = 24

    def __post_init__(self) -> None:
        if not (self.fit_ratio > 1 and self.model_tol >= 0 and self.lag_unc >= 0):
            raise ValueError("HeldOutOptions: fit_ratio > 1, model_tol >= 0 and lag_unc >= 0 required")


@dataclass(frozen=True)
class HeldOutPart:
    """One part's test: ``part`` (``"joint:J"`` or ``"imu:k"``), the chosen answer and its held-out
    variance ratio, the best rival and its ratio, whether it is decided, its confidence and the
    joints to move when it is not."""

    part: str
    answer: str | None
    ratio: float
    rival: str | None
    rival_ratio: float
    decided: bool
    confidence: float
    move: tuple[str, ...] = ()
    fitting_rivals: tuple[str | None, ...] = ()


@dataclass(frozen=True)
class HeldOutTest:
    """Every part's test, the joints too weakly moved to resolve and the band used."""

    parts: dict[str, HeldOutPart]
    weak: tuple[str, ...]
    band_hz: float
    held_out_values: float
    excitation: dict[str, float] = field(default_factory=dict)


class _Data:
    """The window in the comparison band, split in two halves, with the error model."""

    def __init__(self, rec: Recording, opts: HeldOutOptions) -> None:
        from bodyschema import timing as tm

        assert rec.q is not None and rec.qd is not None
        f = tm.median_rate(rec.t)
        bw = stated_filter(rec, FastOptions()).imu_bandwidth
        fc = float(opts.band) if opts.band is not None else tm.choose_band(f, f, bw)
        self.fc, self.rate = fc, f
        self.step = max(1, int(f // (2.5 * fc)))
        T = len(rec.t)
        n_out = -(-T // self.step)
        margin = int(np.ceil(tm.edge_margin(fc) * f / self.step))
        idx = np.arange(n_out)
        mid = n_out // 2
        ok = (idx >= margin) & (idx < n_out - margin)
        self.fold_a = np.flatnonzero(ok & (idx < mid - margin // 2))
        self.fold_b = np.flatnonzero(ok & (idx >= mid + margin // 2))
        if min(len(self.fold_a), len(self.fold_b)) < 50:
            raise ValueError("the window is too short for a held-out test in the comparison band")
        self.q, self.qd, self.gyro = rec.q, rec.qd, rec.gyro
        self.gyroT = np.ascontiguousarray(rec.gyro.transpose(1, 2, 0))  # (K, 3, T)
        self.gb = self.band(rec.gyro, axis=0)  # (Tb, K, 3)
        K = rec.gyro.shape[1]
        self.sigma = tm.gyro_band_noise(rec.gyro, f, fc, bw)
        # per joint: a model's derived velocities carry the noise of the encoders it reads, not the
        # noisiest joint's
        self.qd_var = tm.derivative_noise(tm.position_noise(rec.q), f, fc) ** 2  # (N,)
        gc = self.gb[np.concatenate([self.fold_a, self.fold_b])]
        gc = gc - gc.mean(axis=0)
        ms = np.mean(gc * gc, axis=(0, 2))
        dg = np.diff(gc, axis=0) * (f / self.step)
        f_rms = np.sqrt(np.mean(dg * dg, axis=(0, 2)) / np.maximum(ms, 1e-300)) / (2 * np.pi)
        eps2 = opts.model_tol**2 + (2 * np.pi * f_rms * opts.lag_unc) ** 2
        self.model_var = eps2 * ms + 1e-12  # (K,)
        self.n_eff = min(1.0, 2 * fc * self.step / f)
        qdb = self.band(rec.qd, axis=0)[np.concatenate([self.fold_a, self.fold_b])]
        self.excitation = np.sqrt(np.mean(qdb * qdb, axis=0))
        self.Y = self.gb.reshape(len(self.gb), 3 * K)
        self.c, self.s = np.cos(rec.q), np.sin(rec.q)
        self._cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.gain_tol = opts.gain_tol

    def band(self, x: np.ndarray, axis: int = -1) -> np.ndarray:
        from bodyschema import timing as tm

        return tm.lowpass(x, self.rate, self.fc, axis=axis, step=self.step)

    def heldout_rss(self, h: int, joints: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(K,) held-out residual sum of squares of every IMU's gyro under the model from IMU ``h``
        (or the world, -1) through ``joints`` (one or two hinges, top first), two folds; and (K,)
        whether the fitted hinge is a rotation (:func:`_hinge_gains_ok`)."""
        key = (h, joints)
        if key not in self._cache:
            # the parent's rate less its mean (mostly the gyro's bias): the same model (the mean's
            # rotated parts lie in the cos q, sin q and intercept rows), but A(q) then multiplies the
            # parent's motion, whose norm a rotation keeps (:func:`_hinge_gains_ok`)
            wh = None if h == _WORLD else self.gyroT[h] - self.gyroT[h].mean(axis=1, keepdims=True)
            if len(joints) == 1:
                j = joints[0]
                if wh is None:
                    F = self.qd[None, :, j][:, None, :]  # world: ω = e q̇ + b
                else:
                    F = _hop_features(wh, self.c[None, :, j], self.s[None, :, j], self.qd[None, :, j])
            else:
                a, b = joints
                F = _two_hop_features(
                    None if wh is None else wh[None],
                    self.c[:, a],
                    self.s[:, a],
                    self.qd[:, a],
                    self.c[:, b],
                    self.s[:, b],
                    self.qd[:, b],
                )
            Fb = self.band(F[0])  # (p, Tb)
            rss = _fold_rss(Fb, self.Y, self.fold_a, self.fold_b) + _fold_rss(
                Fb, self.Y, self.fold_b, self.fold_a
            )
            both = np.concatenate([self.fold_a, self.fold_b])
            ok = _hinge_gains_ok(
                Fb[:, both], self.Y[both], h != _WORLD, len(joints), self.n_eff, self.gain_tol
            )
            self._cache[key] = (rss.reshape(-1, 3).sum(-1), ok)
        return self._cache[key]

    @property
    def n_heldout(self) -> int:
        return len(self.fold_a) + len(self.fold_b)


def _hinge_gains_ok(
    F: np.ndarray, Y: np.ndarray, from_imu: bool, hinges: int, n_eff: float, tol: float, z: float = 4.0
) -> np.ndarray:
    """(K,) whether the fitted model is a hinge: the last joint's axis ``e`` (its ``q̇`` row, the last
    row of ``F``) has unit gain, and for one hinge from another IMU, ``A(q) = B0 + B1 cos q + B2 sin q``
    (rows 0-8) keeps the norm of the parent's rate on average over the samples, each within ``tol``
    plus ``z`` standard errors. A linear model can zero any coefficient, so without this a model with
    an extra hinge always fits as well as the one without it (a rival that nests the answer); a
    rotation cannot.
    """
    T = F.shape[1]
    X = np.concatenate([F.T, np.ones((T, 1))], axis=1)
    G = X.T @ X
    G += (1e-9 * np.diag(G) + 1e-300) * np.eye(len(G))
    Ginv = np.linalg.inv(G)
    beta = Ginv @ (X.T @ Y)
    r = Y - X @ beta
    K = Y.shape[1] // 3
    s2 = (np.sum(r * r, axis=0) / max(T - X.shape[1], 1)).reshape(K, 3).mean(-1) / max(n_eff, 1e-6)
    e_row = F.shape[0] - 1
    e = np.linalg.norm(beta[e_row].reshape(K, 3), axis=1)
    se_e = np.sqrt(s2 * Ginv[e_row, e_row])
    ok = np.abs(e - 1.0) <= tol + z * se_e
    if from_imu and hinges == 1:
        # the parent's rotated rate A(q) ω_h keeps the norm of ω_h: compare the fitted contribution's
        # energy with the parent's (along the parent's signal only: a parent turning about one axis
        # leaves the rest of A undetermined, and a gain read from those coefficients means nothing)
        pred = np.einsum("tr,rkc->tkc", X[:, :9], beta[:9].reshape(9, K, 3))
        e_h = float(np.mean(np.sum(F[0:3] ** 2, axis=0)))
        gain = np.sqrt(np.mean(np.sum(pred**2, axis=2), axis=0) / max(e_h, 1e-300))
        # the contribution's standard error, collinearity with the other rows included (a parent
        # that turns with the joint itself leaves the split between A(q) ω_h and e q̇ open)
        X9 = X[:, :9]
        spread = float(np.trace(Ginv[:9, :9] @ (X9.T @ X9))) / T
        se_a = np.sqrt(s2 * spread / max(e_h, 1e-300))
        ok &= np.abs(gain - 1.0) <= tol + z * se_a
    return ok


def _fold_rss(F: np.ndarray, Y: np.ndarray, fit: np.ndarray, test: np.ndarray) -> np.ndarray:
    """Residual sum of squares per column of ``Y`` on samples ``test`` of a least-squares fit of
    ``Y`` on ``F`` (p, T) plus an intercept over samples ``fit``."""
    X = np.concatenate([F.T, np.ones((F.shape[1], 1))], axis=1)
    Xa = X[fit]
    G = Xa.T @ Xa
    G += (1e-9 * np.diag(G) + 1e-300) * np.eye(len(G))
    beta = np.linalg.solve(G, Xa.T @ Y[fit])
    r = Y[test] - X[test] @ beta
    return np.sum(r * r, axis=0)


class _Tree:
    """The chosen tree as indices: joint parents, IMU joints, the IMUs on each link, ancestors."""

    def __init__(self, topo: Topology, joints: list[str], imus: list[str], sigma: np.ndarray) -> None:
        self.jx = {j: i for i, j in enumerate(joints)}
        self.parent = [
            None if topo.joint_parent[j] is None else self.jx[topo.joint_parent[j]] for j in joints
        ]
        self.imu_joint = [None if topo.imu_joint[k] is None else self.jx[topo.imu_joint[k]] for k in imus]
        self.sigma = sigma
        self.on: dict[int | None, list[int]] = {}
        self._subtrees: dict[int, set[int]] = {}
        for k, j in enumerate(self.imu_joint):
            self.on.setdefault(j, []).append(k)

    def chain(self, j: int | None) -> list[int]:
        """Joints from the base down to ``j`` (empty for the base)."""
        out: list[int] = []
        while j is not None:
            out.append(j)
            j = self.parent[j]
        return out[::-1]

    def subtree(self, j: int) -> set[int]:
        """``j`` and every joint below it (kept: each IMU's rivals ask for every joint's)."""
        if j not in self._subtrees:
            self._subtrees[j] = self._grow(j)
        return self._subtrees[j]

    def _grow(self, j: int) -> set[int]:
        out = {j}
        grew = True
        while grew:
            grew = False
            for c, p in enumerate(self.parent):
                if p in out and c not in out:
                    out.add(c)
                    grew = True
        return out

    def source(self, k: int, j: int, parent: int | None) -> tuple[int, tuple[int, ...]] | None:
        """The model for IMU ``k`` on joint ``j`` hung under ``parent``: the nearest IMU other than
        ``k`` up the tree (or the world) and the hinges crossed, top first; None beyond two hinges."""
        hinges = [j]
        p = parent
        while True:
            if p is None:
                return _WORLD, tuple(hinges[::-1])
            others = [m for m in self.on.get(p, []) if m != k]
            if others:
                return min(others, key=lambda m: self.sigma[m]), tuple(hinges[::-1])
            if len(hinges) == 2:
                return None
            hinges.append(p)
            p = self.parent[p]


class _Scorer:
    """Held-out variance ratios of the models a part's answers make, on one window and chosen tree."""

    def __init__(self, data: _Data, tree: _Tree, opts: HeldOutOptions) -> None:
        self.data, self.tree, self.opts = data, tree, opts

    def ratio(self, ks: Iterable[int], model: tuple[int, tuple[int, ...]] | None) -> float:
        """Held-out residual of IMUs ``ks`` under ``model`` over the error model's (inf: no hinge)."""
        if model is None:
            return np.inf
        data = self.data
        h, hinges = model
        rss, ok = data.heldout_rss(h, hinges)
        ks = list(ks)
        if not np.all(ok[ks]):
            return np.inf  # the fitted hinge is no rotation: the answer does not hold
        sig_h = 0.0 if h == _WORLD else data.sigma[h] ** 2
        v = data.sigma[ks] ** 2 + sig_h + np.sum(data.qd_var[list(hinges)]) + data.model_var[ks]
        return float(np.sum(rss[ks]) / (3 * data.n_heldout * np.sum(v)))

    def base_ratio(self, k: int) -> float:
        """IMU ``k`` on the base: its held-out rate against the error model."""
        data = self.data
        y = data.gb[np.concatenate([data.fold_a, data.fold_b]), k]
        y = y - y.mean(axis=0)
        return float(np.mean(y * y) / (data.sigma[k] ** 2 + data.model_var[k]))

    def imu_rivals(self, k: int) -> dict[int | None, float]:
        """IMU ``k`` on each joint (or the base, None): the best ratio of each answer."""
        tree = self.tree
        out: dict[int | None, float] = {None: self.base_ratio(k)}
        for j in range(len(tree.parent)):
            if j == tree.imu_joint[k]:
                out[j] = self.ratio([k], tree.source(k, j, tree.parent[j]))
                continue
            # a rival joint under any parent: which joint carries k must not hang on where the
            # chosen tree put that joint (two joints on one sine swap places with their IMUs)
            below = tree.subtree(j)
            out[j] = min(
                (
                    self.ratio([k], m) if p not in below or self._lifted_fit(m, j) else np.inf
                    for p in [None, *range(len(tree.parent))]
                    if p != j and (m := tree.source(k, j, p)) is not None
                ),
                default=np.inf,
            )
        return out

    def _lifted_fit(self, model: tuple[int, tuple[int, ...]], j: int) -> bool:
        """Joint ``j`` hung under a joint of its own subtree is a tree only with the IMUs ``model``
        reads above ``j`` moved off ``j``'s link, to the link ``j`` hung from: whether they fit there."""
        tree = self.tree
        h = model[0]
        if h == _WORLD or tree.imu_joint[h] != j:
            return True
        up = tree.parent[j]
        r = self.base_ratio(h) if up is None else self.ratio([h], tree.source(h, up, tree.parent[up]))
        return r < self.opts.fit_ratio


def heldout_test(rec: Recording, topo: Topology, options: HeldOutOptions | None = None) -> HeldOutTest:
    """Test every part of ``topo`` (the chosen tree of ``rec``) against its rivals on held-out data
    (the module docstring). ``rec`` needs positions and velocities on one clock (the networks'
    training data: :meth:`Recording.derived`, aligned by :func:`bodyschema.timing.aligned_recording`)."""
    opts = options or HeldOutOptions()
    rec = rec.derived()
    data = _Data(rec, opts)
    joints, imus = list(rec.joint_names), list(rec.imu_names)
    tree = _Tree(topo, joints, imus, data.sigma)
    score = _Scorer(data, tree, opts)
    n_obs = 3 * data.n_heldout * data.n_eff
    parts: dict[str, HeldOutPart] = {}
    for k, imu in enumerate(imus):
        parts[f"imu:{imu}"] = _decide(
            f"imu:{imu}", tree.imu_joint[k], score.imu_rivals(k), opts.fit_ratio, n_obs, tree, joints
        )
    for j, name in enumerate(joints):
        ks = tree.on.get(j, [])
        if not ks:  # a link without IMUs: nothing on it to test
            parts[f"joint:{name}"] = HeldOutPart(
                f"joint:{name}", _name(joints, tree.parent[j]), np.inf, None, np.inf, False, 0.0, (name,)
            )
            continue
        below = tree.subtree(j)
        cands = [p for p in [None, *range(len(joints))] if p is None or p not in below]
        rivals = {p: score.ratio(ks, _models(tree, ks, j, p)) for p in cands}
        parts[f"joint:{name}"] = _decide(
            f"joint:{name}", tree.parent[j], rivals, opts.fit_ratio, n_obs, tree, joints, joint=j
        )
    _links_decided(parts, tree, joints, imus)
    # a joint is too weakly moved when its in-band rate is within the fit test of what a typical model
    # through it leaves: two gyros' noise, the model error and its own derived velocity's noise
    v_ref = float(np.median(2 * data.sigma**2 + data.model_var)) + data.qd_var
    weak = tuple(n for i, n in enumerate(joints) if data.excitation[i] ** 2 / 3 < opts.fit_ratio * v_ref[i])
    exc = {n: float(x) for n, x in zip(joints, data.excitation, strict=True)}
    return HeldOutTest(parts, weak, data.fc, n_obs, exc)


def _links_decided(parts: dict[str, HeldOutPart], tree: _Tree, joints: list[str], imus: list[str]) -> None:
    """A joint's parent is tested on the IMUs of its link and of its parent's link: it stands only
    where those IMUs' own placement does (otherwise the link tested may be another joint's)."""
    for j, name in enumerate(joints):
        key = f"joint:{name}"
        if not parts[key].decided:
            continue
        ks = tree.on.get(j, []) + ([] if tree.parent[j] is None else tree.on.get(tree.parent[j], []))
        open_ = [parts[f"imu:{imus[k]}"] for k in ks if not parts[f"imu:{imus[k]}"].decided]
        if open_:
            move = tuple(sorted({name, *(m for p in open_ for m in p.move)}))
            parts[key] = replace(
                parts[key], decided=False, confidence=min(parts[key].confidence, 0.5), move=move
            )


def _models(tree: _Tree, ks: list[int], j: int, parent: int | None) -> tuple[int, tuple[int, ...]] | None:
    """One model for the IMUs ``ks`` of joint ``j``'s link hung under ``parent``: the source of
    the first of them (the others share its link, so they share the rival's source)."""
    return tree.source(ks[0], j, parent) if len(ks) == 1 else tree.source(-2, j, parent)


def _name(joints: list[str], j: int | None) -> str | None:
    return None if j is None else joints[j]


def _decide(
    part: str,
    chosen: int | None,
    rivals: dict[int | None, float],
    fit_ratio: float,
    n_obs: float,
    tree: _Tree,
    joints: list[str],
    joint: int | None = None,
) -> HeldOutPart:
    """Decided when the chosen answer fits and no rival does; the joints to move otherwise."""
    r_best = rivals[chosen]
    others = {a: r for a, r in rivals.items() if a != chosen}
    rival = min(others, key=lambda a: others[a]) if others else None
    r_rival = others[rival] if others else np.inf
    fitting = _close_rivals(r_best, others, fit_ratio, n_obs)
    fits = r_best < fit_ratio
    decided = bool(fits and not fitting)
    if decided:
        lam = 0.5 * n_obs * (np.log(max(r_rival, 1e-30)) - np.log(max(r_best, 1e-30)))
        conf = float(1.0 / (1.0 + np.exp(-np.clip(lam, -50.0, 50.0))))
        move: tuple[str, ...] = ()
    else:
        conf = 0.0 if not fits else 1.0 / (1.0 + len(fitting))
        alts = fitting if fitting else ((rival,) if rival is not None or others else ())
        moved: set[int] = set()
        own = set(tree.chain(chosen))
        for a in alts:
            moved |= own ^ set(tree.chain(a))
        if joint is not None:
            moved.add(joint)
        elif chosen is not None:
            moved.add(chosen)
        move = tuple(sorted(joints[m] for m in moved))
    return HeldOutPart(
        part,
        _name(joints, chosen),
        float(r_best),
        _name(joints, rival),
        float(r_rival),
        decided,
        conf,
        move,
        tuple(_name(joints, a) for a in fitting),
    )


def _close_rivals(
    r_best: float, others: dict[int | None, float], fit_ratio: float, n_obs: float
) -> tuple[int | None, ...]:
    """The rivals the held-out data do not reject: those that fit (ratio under ``fit_ratio``) and
    either are within chance of the chosen one's ratio, ``r < r_best F⁻¹(1 - α/m; n, n)`` (``n``
    held-out values per answer, ``m`` rivals, ``α`` the fast method's
    :data:`~bodyschema.fast_core.RIVAL_ALPHA`: the fast method's rival test), or leave less than
    :data:`RIVAL_MARGIN` error-model variances more. Acceptance alone is no decision: a rival that
    fits but leaves significantly more residual than the chosen answer, more than the stated model
    error could (a joint's motion it cannot explain), is rejected. The margin keeps the F test from
    deciding on differences the model error makes: two answers both under the error model can differ
    by 15 % on thousands of held-out values (an extra hinge that absorbs part of the gyros' scale
    errors), which chance alone would not explain but the model error does."""
    from scipy.stats import f as f_dist

    m = max(sum(1 for r in others.values() if np.isfinite(r)), 1)
    nu = max(float(n_obs), 1.0)
    bound = float(f_dist.ppf(1.0 - RIVAL_ALPHA / m, nu, nu))
    return tuple(
        a
        for a, r in others.items()
        if r < fit_ratio and (r < max(r_best, 1e-12) * bound or r - r_best < RIVAL_MARGIN)
    )


def heldout_check(rec: Recording, topo: Topology, options: HeldOutOptions | None = None) -> Topology:
    """``topo`` with the held-out tests applied: undetermined parts (and the joints too weakly moved
    to resolve) make it not unique, list the joints to move in ``undetermined`` and their rival trees
    in ``candidates``; every part's confidence is the test's (the dependency threshold's margin is
    no probability), capped at ½ while ``topo`` has joints left out for want of excitation.

    A window too short to split in the comparison band leaves every part undetermined (the networks'
    ranking alone is never reported as sure).
    """
    opts = options or HeldOutOptions()
    try:
        test = heldout_test(rec, topo, opts)
    except ValueError:
        conf = {k: min(v, 0.5) for k, v in topo.confidence.items()}
        und = tuple(sorted(set(topo.undetermined) | set(topo.joint_parent)))
        return replace(topo, unique=False, confidence=conf, undetermined=und)
    conf = dict(topo.confidence)
    move: set[str] = set(topo.undetermined) | set(test.weak)
    cands: list[Topology] = list(topo.candidates)
    for key, p in test.parts.items():
        conf[key] = p.confidence
        if p.decided:
            continue
        move |= set(p.move)
        for alt in p.fitting_rivals or ((p.rival,) if p.rival is not None else ()):
            c = _rival_tree(topo, key, alt)
            if (
                c is not None
                and len(cands) < opts.max_candidates
                and all(not c.same_structure(x) for x in cands)
            ):
                cands.append(c)
    for j in test.weak:
        conf[f"joint:{j}"] = min(conf.get(f"joint:{j}", 0.0), 0.5)
    if topo.undetermined:
        # joints without excitation were left out of the tree (placeholders on the base): one of them
        # could hang anywhere, so no part of the tree stands while there are any
        conf = {k: min(v, 0.5) for k, v in conf.items()}
    undetermined = tuple(j for j in topo.joint_parent if j in move)
    unique = topo.unique and not undetermined
    return replace(topo, unique=unique, confidence=conf, undetermined=undetermined, candidates=tuple(cands))


def _rival_tree(topo: Topology, key: str, alt: str | None) -> Topology | None:
    """``topo`` with part ``key`` given the answer ``alt``, or None when that is no tree."""
    kind, name = key.split(":", 1)
    try:
        if kind == "imu":
            return Topology(joint_parent=dict(topo.joint_parent), imu_joint={**topo.imu_joint, name: alt})
        return Topology(joint_parent={**topo.joint_parent, name: alt}, imu_joint=dict(topo.imu_joint))
    except ValueError:
        return None
