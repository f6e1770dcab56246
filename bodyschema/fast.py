"""Fast topology estimator: which joints move each IMU, from exact linear gyro models.

Why it works (docs/design.md §3):
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
link, and the answer is exact on the tree with those joints contracted.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(1)
>>> T = 2000; t = np.arange(T) / 100
>>> q = np.stack([np.sin(0.9 * t), np.cos(0.6 * t + 1)], 1); qd = np.gradient(q, t, axis=0)
>>> w1 = np.stack([0 * t, 0 * t, qd[:, 0]], 1)                     # link 1 spins about z
>>> c, s = np.cos(q[:, 1]), np.sin(q[:, 1])                        # link 2: x-hinge on link 1
>>> w2 = np.stack([qd[:, 1], s * w1[:, 2], c * w1[:, 2]], 1)
>>> gyro = np.stack([w1, w2], 1) + rng.normal(scale=1e-3, size=(T, 2, 3))
>>> fit = FastEstimator().fit(q, qd, gyro)
>>> fit.dependency_.astype(int).tolist()
[[1, 0], [1, 1]]
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse.csgraph import connected_components

__all__ = ["FastEstimator", "FastFit", "fast_fit", "insufficient_excitation", "noise_level"]

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
    B, T = c.shape
    off = 0 if wh is None else 9
    F = np.empty((B, off + 3, T))
    if wh is not None:
        F[:, 0:3] = wh
        np.multiply(wh, c[:, None, :], out=F[:, 3:6])
        np.multiply(wh, s[:, None, :], out=F[:, 6:9])
    F[:, off] = c
    F[:, off + 1] = s
    F[:, off + 2] = qd
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


# ----------------------------------------------------------------------------------- the estimator
class FastEstimator:
    """Per-IMU ancestor sets from gyro regression tests (see the module docstring for the physics).

    Hyper-parameters
    ----------------
    fit_ratio : residual variance over the noise-only expectation above which a model is rejected.
    rel_tol : relative model error allowed on top of sensor noise (scale nonlinearity, derived
        velocities), as a fraction of the signal RMS.
    min_excitation_snr : a joint is undetermined when its RMS velocity is below this many gyro noise
        standard deviations (the gyros could not tell its two links apart).
    min_excitation : absolute floor on that RMS velocity, rad/s.
    """

    def __init__(
        self,
        fit_ratio: float = 25.0,
        rel_tol: float = 2e-3,
        min_excitation_snr: float = 15.0,
        min_excitation: float = 2e-3,
    ):
        self.fit_ratio = fit_ratio
        self.rel_tol = rel_tol
        self.min_excitation_snr = min_excitation_snr
        self.min_excitation = min_excitation

    def fit(self, q: np.ndarray, qd: np.ndarray, gyro: np.ndarray) -> FastEstimator:
        res = fast_fit(
            q,
            qd,
            gyro,
            fit_ratio=self.fit_ratio,
            rel_tol=self.rel_tol,
            min_excitation_snr=self.min_excitation_snr,
            min_excitation=self.min_excitation,
        )
        self.result_ = res
        self.dependency_ = res.dependency
        self.group_ = res.group
        self.undetermined_ = res.undetermined
        self.imu_confidence_ = res.imu_confidence
        self.joint_confidence_ = res.joint_confidence
        self.excitation_ = res.excitation
        return self


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


def fast_fit(
    q: np.ndarray,
    qd: np.ndarray,
    gyro: np.ndarray,
    fit_ratio: float = 25.0,
    rel_tol: float = 2e-3,
    min_excitation_snr: float = 15.0,
    min_excitation: float = 2e-3,
) -> FastFit:
    """Functional core of :class:`FastEstimator`: ``q``, ``qd`` (T, N), ``gyro`` (T, K, 3) -> FastFit."""
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

    sigma = noise_level(gyro)
    sigma = np.where(np.isfinite(sigma), sigma, 0.0)
    gc = gyro - gyro.mean(axis=0)
    rms = np.sqrt(np.mean(gc * gc, axis=(0, 2)))  # (K,)
    floor = (rel_tol * rms) ** 2 + 1e-12

    excitation = np.sqrt(np.mean(qd * qd, axis=0))
    undetermined = insufficient_excitation(qd, gyro, min_excitation_snr, min_excitation)
    active = np.flatnonzero(~undetermined)

    # ---- same-link and base tests, IMU against IMU
    base_ratio = np.mean(gc * gc, axis=(0, 2)) / (sigma**2 + floor)
    on_base = base_ratio < fit_ratio
    gyroT = np.ascontiguousarray(gyro.transpose(1, 2, 0))  # (K, 3, T)
    Fm = gyroT  # regress on one other IMU
    Y = gc.reshape(T, 3 * K)
    expl = _explained(Fm, Y).reshape(K, K, 3).sum(-1)  # [m, k]
    rss = np.sum(gc * gc, axis=(0, 2))[None, :] - expl
    dof = max(T - 4, 1)
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

    # ---- one-hinge tests, all (child g, parent h, joint j) at once; h == G is the fixed world
    Wg = gc[:, rep, :]  # (T, G, 3)
    Yg = Wg.reshape(T, 3 * G)
    ysq = np.sum(Wg * Wg, axis=(0, 2))
    sig_g = sigma[rep]
    cos_q, sin_q = np.cos(q[:, active]), np.sin(q[:, active])
    qda = qd[:, active]
    Na = len(active)
    cosT, sinT, qdT = (np.ascontiguousarray(x.T) for x in (cos_q, sin_q, qda))
    ratio = np.full((G, G + 1, Na), np.inf)
    s2 = np.full((G, G + 1, Na), np.inf)  # residual variance per output
    if G and Na:
        for h in range(G + 1):
            if h == G:
                F = qdT[:, None, :]  # world: ω_g = e q̇_j + b
                exp_var = sig_g**2 + floor[rep]
            else:
                F = _hop_features(gyroT[rep[h]], cosT, sinT, qdT)
                exp_var = sig_g**2 + sig_g[h] ** 2 + floor[rep]
            ex = _explained(F, Yg).reshape(Na, G, 3).sum(-1)  # (Na, G)
            dof = max(T - F.shape[1] - 1, 1)
            s2[:, h, :] = ((ysq[None, :] - ex) / (3 * dof)).T
            ratio[:, h, :] = s2[:, h, :] / exp_var[:, None]
        for g in range(G):
            ratio[g, g, :] = np.inf
            s2[g, g, :] = np.inf

    # ---- spanning forest over groups + world from accepted one-hinge edges (cheapest first)
    world = G
    # Ordered by a BIC-type score: the world model (1 regressor) is nested in every one-hinge model
    # (12), so a child of the base fits below any of its siblings too; parsimony must pick the world.
    n_obs = 3 * T
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
    tree_edges: list[tuple[int, int, tuple[int, ...], float]] = []  # (node, node, active joints, ratio)
    for _, r, g, h, a in cand:
        if a in used or uf.find(g) == uf.find(h):
            continue
        uf.union(g, h)
        used.add(a)
        tree_edges.append((g, h, (a,), r))

    # ---- two-hinge edges to attach what is left (a link without IMUs in between). The model from h
    # to g crossing (a then b) is the model from g to h crossing (b then a); both directions must pass.
    # Batched like the one-hinge tests: per ordered joint pair, one solve for all parents and children.
    spare = [a for a in range(Na) if a not in used]
    if len(spare) >= 2 and len({uf.find(x) for x in range(G + 1)}) > 1:
        pairs = [(a, b) for a in spare for b in spare if a != b]
        pindex = {pq: i for i, pq in enumerate(pairs)}
        r2 = np.full((G, G + 1, len(pairs)), np.inf)
        wall = gyroT[rep]  # (G, 3, T)
        for i, (a, b) in enumerate(pairs):
            args = (cos_q[:, a], sin_q[:, a], qda[:, a], cos_q[:, b], sin_q[:, b], qda[:, b])
            for h_slice, wh in ((slice(0, G), wall), (slice(G, G + 1), None)):
                F = _two_hop_features(wh, *args)
                ex = _explained(F, Yg).reshape(F.shape[0], G, 3).sum(-1)  # (H, G)
                dof = max(T - F.shape[1] - 1, 1)
                hs = np.arange(G + 1)[h_slice]
                par_var = np.where(hs == world, 0.0, sig_g[hs % G] ** 2)[:, None]
                ev = sig_g[None, :] ** 2 + floor[rep][None, :] + par_var
                r2[:, h_slice, i] = (((ysq[None, :] - ex) / (3 * dof)) / ev).T
            for g in range(G):
                r2[g, g, i] = np.inf
        cand2: list[tuple[float, int, int, tuple[int, int]]] = []
        for g in range(G):
            for h in range(G + 1):
                for i, (a, b) in enumerate(pairs):
                    r = r2[g, h, i] if h == world else max(r2[g, h, i], r2[h, g, pindex[(b, a)]])
                    if r < fit_ratio:
                        cand2.append((float(r), g, h, (a, b)))
        cand2.sort()
        for r, g, h, ab in cand2:
            if uf.find(g) != uf.find(h):
                uf.union(g, h)
                tree_edges.append((g, h, ab, r))

    # ---- orient from the world; ancestor set = symmetric difference of joints along the path
    nbrs: dict[int, list[tuple[int, tuple[int, ...], float]]] = {x: [] for x in range(G + 1)}
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

    # ---- confidence: likelihood ratio of the chosen edge against the best rival attachment
    # BIC-type log likelihood ratio of the chosen attachment against the best rival one. Rivals are all
    # other (parent, joint) models for this group except the reversed edges of its own tree children
    # (those describe the same hinge). Nested rivals (a sibling's model around a base joint) pay their
    # extra parameters, so they do not erode the confidence.
    edge_conf = np.zeros(G)
    half_log_n = 0.5 * np.log(n_obs)
    for g in range(G):
        if g not in parent_of:
            continue
        h, js, r = parent_of[g]
        child_edges = {(y, yjs[0]) for y, yjs, _ in nbrs[g] if y != h and len(yjs) == 1}
        p_best = 1 if h == world else 12 if len(js) == 1 else 40
        s2_best = max(r * (sig_g[g] ** 2 + floor[rep[g]] + (0 if h == world else sig_g[h] ** 2)), 1e-30)
        lam = np.inf
        for h2 in range(G + 1):
            p2 = 1 if h2 == world else 12
            for a in range(Na):
                if (h2 == h and (a,) == js) or (h2, a) in child_edges or not np.isfinite(s2[g, h2, a]):
                    continue
                ll = 0.5 * n_obs * (np.log(max(s2[g, h2, a], 1e-30)) - np.log(s2_best))
                lam = min(lam, ll + (p2 - p_best) * half_log_n)
        fit_ok = 1.0 if r <= fit_ratio else fit_ratio / r
        edge_conf[g] = fit_ok / (1.0 + np.exp(-float(np.clip(lam, -50.0, 50.0))))

    dep = np.zeros((K, N), dtype=bool)
    imu_conf = np.zeros(K)
    for k in range(K):
        g = group[k]
        if g < 0:
            # a non-rotating IMU: confident in proportion to how clearly it does not rotate
            imu_conf[k] = float(np.clip(1.5 - base_ratio[k] / fit_ratio, 0.0, 1.0))
            continue
        if g in anc:
            for a in anc[g]:
                dep[k, active[a]] = True
            imu_conf[k] = min(edge_conf[g], member_conf[k])
    joint_conf = np.zeros(N)
    child_of_joint: dict[int, int] = {}
    for g, (_, js, _) in parent_of.items():
        for a in js:  # both joints of a two-hinge edge: their order is the completion's business
            child_of_joint[a] = g
    for a in range(Na):
        g = child_of_joint.get(a)
        if g is None:
            continue
        h = parent_of[g][0]
        up = 1.0 if h == world else edge_conf[h]
        joint_conf[active[a]] = min(edge_conf[g], up)

    edges = [
        (g, (-1 if h == world else h), tuple(int(active[a]) for a in js), float(r))
        for g, (h, js, r) in parent_of.items()
    ]
    return FastFit(
        dependency=dep,
        group=group,
        undetermined=np.flatnonzero(undetermined),
        imu_confidence=imu_conf,
        joint_confidence=joint_conf,
        excitation=excitation,
        noise=sigma,
        edges=edges,
    )
