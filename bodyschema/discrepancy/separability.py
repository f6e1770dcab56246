"""Which effects a recording can tell apart: the overlap of two effects' signatures and where it
makes a named value untrustworthy.

Some effects leave nearly the same residual on some motions. Where the sensor hardly turns, a
constant accelerometer bias (sensor frame) and a tilt of gravity (world frame, seen as ``R^T dg``)
are both a constant accelerometer offset: the data fix their sum, not the split. An analysis that
names one of them then reports the sum as that effect, with the narrow interval of a model in which
the other is absent by assumption.

**The measure.** The largest canonical correlation ``rho`` between the two effects' signatures (their
columns of the normalised model Jacobian over the usable samples, both channels stacked), after the
other effects of the model are projected out of both (what each adds to the model). ``rho = 1``:
some change of one is exactly some change of the other; ``rho = 0``: nothing of one looks like the
other.

**The cut, from the noise model.** Let ``a`` be named and ``b`` not. Given ``a``, a change of ``b``
goes unseen up to its detection limit, ``sqrt(w)`` standard errors of ``b`` given ``a`` (``w``: the
critical Wald statistic of the evidence test at the level the selection names at, with the pair's
smaller number of parameters, :func:`~bodyschema.discrepancy.evidence.critical_wald`). In the
direction of largest overlap that standard error is ``1 / sqrt(1 - rho^2)`` times ``b``'s alone, and
an ignored ``b`` moves ``a``'s estimate by ``rho`` times ``b``'s change (both in units of their own
standard errors, white noise). So a ``b`` the recording cannot reveal shifts ``a`` by up to
``rho * sqrt(w) / sqrt(1 - rho^2)`` of ``a``'s standard errors. When that exceeds the 95 %
half-width ``z`` (1.96), ``a``'s interval is narrower than what the data know, and the two are
reported jointly:

    not separable  <=>  rho^2 > z^2 / (z^2 + w).

With the usual level (0.01 split over about a dozen tests) and 3-parameter effects, ``w`` is 20-30
and the cut ``rho`` about 0.35-0.45. Past the cut an effect keeps its own name only where its
evidence holds with the other effect in the model (:func:`bodyschema.discrepancy.selection.analyze`);
two named effects are judged alike, each with the other in the model.

**Groups.** Named effects that overlap beyond the cut are one group (transitively); an effect not
named joins the group of the named effect it overlaps most. A group is named as one
(``"acc_bias or gravity"``), with its **joint value** in the parameters of its first effect (library
order): the change of the first that takes up the others' on this recording,
``first + sum_e M_e (e - e0)``, with ``M_e`` the regression of ``e``'s signature on the first's given
the model outside the group (:func:`joint_maps`).

Gravity's magnitude is held at the reference's whenever an accelerometer bias or scale is in the
model (:func:`bodyschema.discrepancy.fit.fit_params`), so only its tilt enters: the two columns
perpendicular to the reference gravity.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bodyschema.discrepancy.effects import EFFECTS
from bodyschema.discrepancy.evidence import critical_wald, n_clusters, signatures
from bodyschema.discrepancy.fit import Problem

__all__ = [
    "SEPARATE_BY",
    "Z95",
    "Overlap",
    "Signatures",
    "groups",
    "joint_cut",
    "joint_maps",
    "overlaps",
    "separate_by",
    "signature_columns",
]

#: Two-sided 95 % normal quantile: a named effect's interval is ``Z95`` standard errors either side.
Z95 = 1.959963984540054

#: Relative singular value below which a signature direction counts as absent (rank).
_RANK_TOL = 1e-8

#: What motion reveals each effect apart from the others (the advice of a joint name).
SEPARATE_BY: dict[str, str] = {
    "time_offset": "faster changes of the motion (angular acceleration, jerk)",
    "gyro_bias": "rest, or rotation both ways about every axis",
    "acc_bias": "orientation changes: hold or turn the sensor in several attitudes (a bias turns with it)",
    "gyro_scale": "faster rotation about every axis",
    "acc_scale": "larger accelerations on every axis (several attitudes, faster translation)",
    "mounting_rotation": "rotation about several axes",
    "lever_arm": "faster rotation (the lever-arm acceleration grows with the rate squared)",
    "gravity": "orientation changes: tilt the sensor about horizontal axes (gravity stays in the world)",
}

#: Advice for the pairs whose separating motion is one and the same.
_PAIR_ADVICE: dict[frozenset[str], str] = {
    frozenset({"acc_bias", "gravity"}): (
        "orientation changes: rotate the sensor through several attitudes (tilt it about horizontal "
        "axes); a sensor-frame bias turns with the sensor, a world-frame gravity error does not"
    ),
}


@dataclass(frozen=True)
class Overlap:
    """How much a named effect's signature shares with another effect's on this recording.

    ``named``: in the model; ``partner``: the other (named or not); ``correlation``: largest
    canonical correlation of their signatures given the rest of the model; ``cut``: the correlation
    above which they are reported jointly (:func:`joint_cut`).
    """

    named: str
    partner: str
    correlation: float
    cut: float

    @property
    def separable(self) -> bool:
        return self.correlation <= self.cut


@dataclass(frozen=True)
class Signatures:
    """Each effect's signature columns over the usable samples (both channels stacked) and the map
    from its parameters to their coefficients (identity, or gravity's tilt basis)."""

    columns: dict[str, np.ndarray]
    to_coef: dict[str, np.ndarray]
    clusters: int
    #: Each effect's columns for all its parameters (gravity's magnitude too: what a change of it
    #: does to the readings, for :func:`joint_maps`).
    full: dict[str, np.ndarray]

    def given(self, names: Sequence[str]) -> np.ndarray | None:
        """Orthonormal basis of the signatures of ``names`` (None for none)."""
        names = [n for n in names if n in self.columns]
        return _orth(np.concatenate([self.columns[n] for n in names], axis=1)) if names else None


def separate_by(effects: Sequence[str]) -> str:
    """The motion that would tell the ``effects`` apart."""
    advice = _PAIR_ADVICE.get(frozenset(effects))
    if advice is not None:
        return advice
    return "; ".join(dict.fromkeys(SEPARATE_BY.get(e, e) for e in effects))


def joint_cut(w_crit: float) -> float:
    """The canonical correlation above which an unseen partner may move a named effect beyond its
    95 % interval: ``z / sqrt(z^2 + w)`` (see the module docstring).

    >>> round(joint_cut(25.0), 3)
    0.365
    """
    return float(Z95 / np.sqrt(Z95**2 + w_crit))


def _tilt_basis(prob: Problem) -> np.ndarray | None:
    """(3, 2) orthonormal directions perpendicular to the reference gravity (None without one)."""
    g = np.asarray(prob.ref.gravity, dtype=np.float64).reshape(3)
    if not np.any(g != 0.0):
        return None
    u, _, _ = np.linalg.svd(g.reshape(3, 1))
    return u[:, 1:]


def _orth(X: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the column space of ``X`` (directions below :data:`_RANK_TOL` dropped)."""
    if X.shape[1] == 0:
        return X
    u, s, _ = np.linalg.svd(X, full_matrices=False)
    keep = s > _RANK_TOL * max(float(s[0]), 1e-300)
    return u[:, keep]


def _project_out(X: np.ndarray, Q: np.ndarray | None) -> np.ndarray:
    return X if Q is None or Q.shape[1] == 0 else X - Q @ (Q.T @ X)


def signature_columns(
    prob: Problem, params: Mapping[str, Mapping[str, object]], names: Sequence[str], block_s: float
) -> Signatures:
    """The :class:`Signatures` of the effects ``names`` around the fit ``params``; ``block_s``: the
    evidence's time blocks (the cut's degrees of freedom)."""
    J, _, cols = signatures(prob, params, names)
    idx = prob.index
    X = J[idx].reshape(idx.size * 6, -1)
    full = {n: X[:, c] for n, c in cols.items()}
    out, to_coef = dict(full), {n: np.eye(c.size) for n, c in cols.items()}
    tilt = _tilt_basis(prob)
    if "gravity" in cols and tilt is not None:
        out["gravity"] = full["gravity"] @ tilt
        to_coef["gravity"] = tilt.T
    return Signatures(out, to_coef, n_clusters(prob, block_s), full)


def overlaps(
    sig: Signatures, model: Sequence[str], candidates: Sequence[str], *, level: float
) -> list[Overlap]:
    """The overlap of every effect of ``model`` with every other effect of ``candidates`` (each pair of
    named effects once), given the rest of the model; ``level``: the per-test level the selection
    names at (the cut's critical value)."""
    order = [n for n in EFFECTS if n in sig.columns]
    out = []
    for a in (n for n in order if n in model):
        for b in (n for n in order if n in candidates and n != a):
            if b in model and order.index(b) < order.index(a):
                continue
            Q = sig.given([n for n in model if n not in (a, b)])
            Ua = _orth(_project_out(sig.columns[a], Q))
            Ub = _orth(_project_out(sig.columns[b], Q))
            if Ua.shape[1] == 0 or Ub.shape[1] == 0:
                continue
            rho = float(min(np.linalg.svd(Ua.T @ Ub, compute_uv=False)[0], 1.0))
            k = min(Ua.shape[1], Ub.shape[1])
            out.append(Overlap(a, b, rho, joint_cut(critical_wald(level, k, sig.clusters))))
    return out


def groups(found: Sequence[Overlap], model: Sequence[str]) -> list[list[str]]:
    """The effects to name jointly, in library order per group: named effects whose overlap is beyond
    the cut are one group (transitively), and an effect not named joins the group of the named
    effect it overlaps most, beyond the cut."""
    parent = {n: n for n in model}

    def root(n: str) -> str:
        while parent[n] != n:
            n = parent[n]
        return n

    joint = [o for o in found if not o.separable]
    for o in (o for o in joint if o.partner in parent):
        parent[root(o.partner)] = root(o.named)
    members: dict[str, set[str]] = {}
    for n in model:
        members.setdefault(root(n), set()).add(n)
    for o in sorted((o for o in joint if o.partner not in parent), key=lambda o: -o.correlation):
        if not any(o.partner in m for m in members.values()):
            members[root(o.named)].add(o.partner)
    order = list(EFFECTS)
    return [sorted(m, key=order.index) for m in members.values() if len(m) > 1]


def joint_maps(sig: Signatures, group: Sequence[str], model: Sequence[str]) -> dict[str, np.ndarray]:
    """For every effect of ``group`` but the first: (size of first, size of it) the change of the
    first that takes up a unit change of it on this recording, given the model outside the group."""
    Q = sig.given([n for n in model if n not in group])
    first = group[0]
    Xf = _project_out(sig.columns[first], Q)
    out = {}
    for n in group[1:]:
        coef = np.linalg.lstsq(Xf, _project_out(sig.full[n], Q), rcond=None)[0]
        out[n] = np.linalg.pinv(sig.to_coef[first]) @ coef
    return out
