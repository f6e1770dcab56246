"""Least-squares fit of IMU error effects to measured readings, on any subset of the samples.

The data are first brought to a common band (:func:`prepare`): the reference-derived readings and the
measured ones are low-passed alike (zero phase) and decimated to an analysis rate, and samples near
gaps of the reference are masked. Residuals are normalised per channel (gyro, accelerometer) by the
RMS residual of the ideal model, each channel at its own best time offset (floored, so a near-perfect
recording does not blow small numeric errors up), which makes the *score* — the mean squared
normalised residual averaged over both channels — start at about 1 and makes gains fractions of the
original residual energy.

Example
-------
>>> import numpy as np
>>> from bodyschema.rigid_motion import reference_motion, smooth_random_motion
>>> m = smooth_random_motion(20.0, 100.0, np.random.default_rng(0))
>>> ref = reference_motion(m["t"], m["quat"], m["pos"])
>>> gyro = m["gyro"] + [0.05, 0.0, 0.0]
>>> prob = prepare(ref, gyro, m["acc"], cutoff=None, analysis_rate=None)
>>> p = fit_params(prob, ["gyro_bias"], {}, prob.index)
>>> np.round(p["gyro_bias"]["vector"], 3).tolist()[0]
0.05
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import binary_erosion
from scipy.optimize import leastsq

from bodyschema.discrepancy.effects import EFFECTS, Params, nominal, pack, predict, predict_rows, unpack
from bodyschema.rigid_motion import ReferenceMotion, lowpass

__all__ = [
    "Problem",
    "block_folds",
    "fit_params",
    "jacobian",
    "normalized_residual",
    "prepare",
    "residual",
    "score",
    "shifted_residuals",
]

#: Bounds of each parameter's deviation from null (wide: they only keep the optimiser sane).
_BOUND = {
    "time_offset": 0.25,
    "gyro_bias": 5.0,
    "acc_bias": 20.0,
    "gyro_scale": 0.5,
    "acc_scale": 0.5,
    "mounting_rotation": 4.0,
    "lever_arm": 1.0,
    "gravity": 5.0,
}

#: Typical size and bound of a gravity fit on a gravity-free reference (the sensor networks' Eq. 11):
#: all of gravity may be missing, in any direction: a deviation of 9.81 m/s² is about one unit of the
#: optimiser's variables, not 500 of the usual 0.02 m/s².
_NO_GRAVITY = (10.0, 15.0)


def _scale(name: str, ref: ReferenceMotion) -> tuple[float, float]:
    """``(typical, bound)`` of one parameter of effect ``name`` around its nominal value."""
    if name == "gravity" and not np.any(np.asarray(ref.gravity) != 0.0):
        return _NO_GRAVITY
    return EFFECTS[name].typical, _BOUND[name]


@dataclass(frozen=True)
class Problem:
    """Measured and reference readings on one time grid, with the samples that may be used.

    ``ref`` and ``gyro``/``acc`` (T, 3) share ``ref.t`` (the analysis grid); ``index`` holds the
    usable sample indices; ``scale`` the per-channel normalisation (gyro rad/s, acc m/s²); ``rate``
    the analysis rate. ``t_full``/``meas_full`` (T_full, 6) keep the low-passed measured readings at
    the recorded rate, so that a time offset can be fitted without interpolating the coarse grid.
    """

    ref: ReferenceMotion
    gyro: np.ndarray
    acc: np.ndarray
    index: np.ndarray
    scale: np.ndarray
    rate: float
    t_full: np.ndarray | None = None
    meas_full: np.ndarray | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def measured(self, seconds: float = 0.0) -> np.ndarray:
        """(T, 6) measured gyro and acc at ``t + seconds`` (edge-held), on the analysis grid.

        For the fit, ``measured(t) = model(t - tau)`` is evaluated as ``measured(t + tau) =
        model(t)``: the same model, but the shift interpolates the finely sampled measurement.
        Shifting the decimated prediction instead (linear interpolation between samples ~10 ms apart)
        attenuates a 3-5 Hz motion by 0.5-1.5 %, which a gyro scale then absorbs.
        """
        hit = self._cache.get("measured")  # (offset, readings) of the last call
        if hit is not None and hit[0] == seconds:
            return hit[1].copy()
        if seconds == 0.0 or self.t_full is None or self.meas_full is None:
            out = np.concatenate([self.gyro, self.acc], axis=1)
            self._cache["measured"] = (seconds, out)
            return out.copy()
        # Cubic interpolation, edge-held: a linear one attenuates the motion between samples by up to
        # (1 - cos(w h)) / 2 (0.5 % for 3 Hz at 100 Hz), a residual proportional to the reading that
        # a gyro or acc scale then takes up once the delay itself is explained.
        spline = self._cache.get("spline")
        if spline is None:
            spline = CubicSpline(self.t_full, self.meas_full, axis=0, extrapolate=False)
            self._cache["spline"] = spline
        tq = np.clip(self.ref.t + seconds, self.t_full[0], self.t_full[-1])
        out = spline(tq)
        self._cache["measured"] = (seconds, out)  # fits ask again for the same offset
        return out.copy()

    def measured_rows(self, seconds: float, rows: np.ndarray) -> np.ndarray:
        """``measured(seconds)[rows]``, computed on those rows only (the interpolation is pointwise,
        so each row is the same number :meth:`measured` gives). Returns a new array."""
        if seconds == 0.0 or self.t_full is None or self.meas_full is None:
            return np.concatenate([self.gyro, self.acc], axis=1)[rows]
        spline = self._cache.get("spline")
        if spline is None:
            spline = CubicSpline(self.t_full, self.meas_full, axis=0, extrapolate=False)
            self._cache["spline"] = spline
        return spline(np.clip(self.ref.t[rows] + seconds, self.t_full[0], self.t_full[-1]))


def prepare(
    ref: ReferenceMotion,
    gyro: np.ndarray,
    acc: np.ndarray,
    valid: np.ndarray | None = None,
    cutoff: float | None = 10.0,
    analysis_rate: float | None = 100.0,
    margin: float = 0.25,
    scale_floor: tuple[float, float] = (0.002, 0.02),
) -> Problem:
    """Low-pass the measured readings like the reference, decimate, mask and normalise.

    ``ref`` must already be low-passed at ``cutoff`` (:func:`bodyschema.rigid_motion.reference_motion`).
    ``valid`` (T,) marks samples with a trustworthy reference; ``margin`` seconds around every invalid
    stretch and at both ends are dropped as well (filter and difference transients).
    """
    g = np.asarray(gyro, dtype=np.float64)
    a = np.asarray(acc, dtype=np.float64)
    T = ref.t.shape[0]
    if g.shape != (T, 3) or a.shape != (T, 3):
        raise ValueError(f"gyro and acc must have shape {(T, 3)}, got {g.shape} and {a.shape}")
    ok = np.all(np.isfinite(g), axis=1) & np.all(np.isfinite(a), axis=1)
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape != (T,):
            raise ValueError(f"valid must have shape {(T,)}, got {v.shape}")
        ok &= v
    if not ok.any():
        raise ValueError("no sample has both a finite IMU reading and a valid reference")
    g = np.where(ok[:, None], g, 0.0)
    a = np.where(ok[:, None], a, 0.0)
    rate = float(1.0 / np.median(np.diff(ref.t)))
    g = lowpass(g, rate, cutoff)
    a = lowpass(a, rate, cutoff)
    m = max(1, round(margin * rate))
    ok = binary_erosion(ok, structure=np.ones(2 * m + 1, dtype=bool), border_value=0)
    step = 1 if analysis_rate is None else max(1, round(rate / analysis_rate))
    sl = slice(0, T, step)
    ref_d = ref.select(sl)
    ok_d = ok[sl]
    index = np.flatnonzero(ok_d)
    if index.size < 20:
        raise ValueError(f"only {index.size} usable samples after masking; need at least 20")
    full = np.concatenate([g, a], axis=1)
    prob = Problem(ref_d, g[sl], a[sl], index, np.ones(2), rate / step, ref.t, full)
    scale = np.maximum(_aligned_rms(prob), np.asarray(scale_floor, dtype=np.float64))
    return replace(prob, scale=scale, _cache={})


def _aligned_rms(prob: Problem) -> np.ndarray:
    """Each channel's residual RMS against the bare model, at that channel's own best time offset.

    The scales weigh the gyro against the accelerometer in every fit, so they must not move when the
    whole recording is shifted in time. Taken at offset zero they did: a delay raises the gyro's RMS
    far more than the accelerometer's (on BROAD trial 09, +0.9 ms moved the gyro's scale from 0.182
    to 0.220 rad/s and the acc's from 0.414 to 0.423 m/s²), and where the two channels prefer
    slightly different offsets (4.15 ms against 3.5 ms there) the fitted offset followed the weight
    to the accelerometer: 93 % of a hidden 0.9 ms delay came back, 3 sigma short; 24.54 of 25 ms on
    trial 07. Aligned per channel, 99.98 % and 25.000 ms. A coarse grid over the offset's bound, two
    analysis samples apart, then a bounded search around its best point.
    """
    from scipy.optimize import minimize_scalar

    _, pred = residual(prob, {})
    idx = prob.index
    step = 2.0 / prob.rate
    grid = np.arange(-_BOUND["time_offset"], _BOUND["time_offset"] + step / 2, step)
    channels = (slice(0, 3), slice(3, 6))
    # one shift of the measurement per grid point serves both channels
    at = np.array(
        [
            [np.sqrt(np.mean(r[:, c] ** 2)) for c in channels]
            for _, r in shifted_residuals(prob, pred, grid, idx)
        ]
    )
    out = []
    for k, cols in enumerate(channels):

        def rms(tau: float, cols: slice = cols) -> float:
            ((_, r),) = shifted_residuals(prob, pred, np.array([tau]), idx)
            return float(np.sqrt(np.mean(r[:, cols] ** 2)))

        i = int(np.argmin(at[:, k]))
        found = minimize_scalar(
            rms, bounds=(grid[i] - step, grid[i] + step), method="bounded", options={"xatol": 1e-6}
        )
        out.append(min(float(found.fun), float(at[i, k])))
    return np.array(out)


def shifted_residuals(
    prob: Problem, pred: np.ndarray, offsets: np.ndarray, index: np.ndarray
) -> Iterator[tuple[float, np.ndarray]]:
    """``(offset, measured(offset) - pred)`` on the samples ``index``, for each offset of a grid.

    ``pred`` (T, 6) is the model's prediction without a time offset, computed once by the caller; only
    the measurement is shifted (:meth:`Problem.measured_rows`), as a time-offset fit does. A time
    offset's cost is not convex, so its fit starts from the best of such a grid, and the channel
    scales are taken at each channel's best.
    """
    for tau in offsets:
        yield float(tau), prob.measured_rows(float(tau), index) - pred[index]


def block_folds(index: np.ndarray, n_blocks: int) -> list[np.ndarray]:
    """Split the usable sample indices into ``n_blocks`` contiguous blocks of (nearly) equal size.

    >>> [b.tolist() for b in block_folds(np.arange(7), 3)]
    [[0, 1, 2], [3, 4], [5, 6]]
    """
    if n_blocks < 2:
        raise ValueError("need at least 2 blocks")
    if index.size < 2 * n_blocks:
        raise ValueError(f"{index.size} samples are too few for {n_blocks} blocks")
    return [np.asarray(b) for b in np.array_split(index, n_blocks)]


def residual(prob: Problem, params: Mapping[str, Mapping[str, object]]) -> tuple[np.ndarray, np.ndarray]:
    """``(residual, prediction)``, each (T, 6) gyro then acc: measured minus the model, in units.

    The time offset is applied to the measurement (see :meth:`Problem.measured`); the prediction
    returned is the unshifted model, aligned with the residual's samples.
    """
    tau = 0.0
    if "time_offset" in params:
        tau = float(EFFECTS["time_offset"].from_params(params["time_offset"])[0])
        params = {k: v for k, v in params.items() if k != "time_offset"}
    gp, ap = predict(prob.ref, params)
    pred = np.concatenate([gp, ap], axis=1)
    return prob.measured(tau) - pred, pred


def normalized_residual(prob: Problem, params: Mapping[str, Mapping[str, object]]) -> np.ndarray:
    """(T, 6) measured minus predicted, gyro then acc, each divided by its channel scale."""
    r, _ = residual(prob, params)
    r[:, :3] /= prob.scale[0]
    r[:, 3:] /= prob.scale[1]
    return r


def score(resid: np.ndarray, index: np.ndarray) -> float:
    """Mean squared normalised residual over ``index`` (both channels weigh alike)."""
    return float(np.mean(resid[index] ** 2))


def fit_params(
    prob: Problem,
    names: Sequence[str],
    init: Mapping[str, Mapping[str, object]],
    index: np.ndarray,
    max_nfev: int | None = None,
) -> Params:
    """Least-squares fit of the effects ``names`` on the samples ``index``; others stay as in ``init``.

    Returns all effects of ``init`` plus ``names`` (the fitted ones replaced). The effect's own ``fit``
    is this with one name: the rest of the model is held fixed.
    """
    free = [n for n in EFFECTS if n in names]
    if any(n == "noise" or n not in EFFECTS for n in names):
        raise ValueError(f"cannot least-squares fit {list(names)}; fittable: {list(_BOUND)}")
    fixed: Params = {k: dict(v) for k, v in init.items() if k not in free}
    x0 = pack(init, free, prob.ref)
    null = pack({}, free, prob.ref)
    width = np.concatenate([np.full(EFFECTS[n].size, _scale(n, prob.ref)[1]) for n in free])
    x_scale = np.concatenate([np.full(EFFECTS[n].size, _scale(n, prob.ref)[0]) for n in free])
    x0 = np.clip(x0, null - width * 0.999, null + width * 0.999)

    # The optimiser works on z = 1 + (x - null) / typical: O(1) everywhere. MINPACK sizes its first
    # trust region by |z|, so a variable starting at (almost) zero — an offset, a bias — would
    # otherwise be stuck there. With gravity's magnitude pinned, gravity's three entries of z are its
    # tilt and magnitude instead, in the same units (:class:`_Variables`).
    pin = _pinned_gravity(prob, free, fixed, index.size)
    var = _Variables(null, x_scale, free if pin is not None else None)

    # A pull towards "effect absent" (weight 1e-12 per typical magnitude squared, relative to a score
    # of 1): it keeps directions the data cannot see at all — a lever arm along the only axis a link
    # turns about — at null instead of drifting. It must stay below what the data see of the weakest
    # direction anyone reads a value along, or it biases that value: a pull acts on a direction the
    # data see with curvature c (score per typical squared) as a shrinkage by w / (c + w). At weight
    # 1e-6 it did: where an accelerometer bias and a gravity tilt nearly share a signature (a BROAD
    # translation trial, c about 4e-6 apart from each other), a fifth of a hidden tilt went to the
    # bias, 4-6 standard errors off; beside a 25 ms delay it held a 3 deg/s gyro bias to 80 % of
    # itself. Nothing real sits as low as 1e-12: the finite-difference columns alone are that coarse.
    ridge = 1e-6 * np.sqrt(6 * index.size)
    obj = _Objective(var, _Rows(prob, fixed, free, index), ridge, pin, index.size)

    # Levenberg-Marquardt (MINPACK's lmder, QR) is several times faster here than the bounded
    # trust-region method, whose exact solver takes an SVD of the full Jacobian every step; the
    # bounds are only a sanity clamp, applied after. ``leastsq`` makes the same MINPACK call as
    # ``least_squares(method="lm")`` with the same tolerances (``gtol`` is least_squares' default),
    # but takes the Jacobian in MINPACK's own column-major layout and evaluates nothing beyond what
    # MINPACK asks for.
    z0 = var.z(x0)
    if not np.all(np.isfinite(obj.fun(z0))):
        raise ValueError("Residuals are not finite in the initial point.")
    z, *_ = leastsq(
        obj.fun,
        z0,
        Dfun=obj.jac,
        full_output=True,
        col_deriv=True,
        ftol=1e-7,
        xtol=1e-7,
        gtol=1e-8,
        maxfev=max_nfev or 30 * (x0.size + 1),
    )
    x = np.clip(var.x(z), null - width, null + width)
    out = dict(fixed)
    out.update(unpack(x, free))
    return {n: out[n] for n in EFFECTS if n in out}


class _Objective:
    """What :func:`fit_params` hands MINPACK: the residual rows at z and their Jacobian, each cached for
    the last point asked (the optimiser asks for the same point more than once)."""

    def __init__(
        self, var: _Variables, model: _Rows, ridge: float, pin: tuple[float, float] | None, n: int
    ) -> None:
        self.var, self.model, self.ridge, self.pin, self.n = var, model, ridge, pin, n
        self.n6 = 6 * n
        self._cache: dict[bytes, np.ndarray] = {}
        self._last: dict[bytes, np.ndarray] = {}

    def extra(self, z: np.ndarray, x: np.ndarray, p: Params) -> list[np.ndarray]:
        """The rows after the data's: the ridge, and the magnitude pin when there is one."""
        rows = [self.ridge * self.var.deviation(z, x)]
        return rows if self.pin is None else [*rows, _pin_row(p, self.pin)]

    def fun(self, z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in self._cache:
            self._cache.clear()
            x = self.var.x(z)
            p = self.model.params(x)
            self._cache[key] = np.concatenate([self.model.rows(p).ravel(), *self.extra(z, x, p)])
        return self._cache[key]

    def jac(self, z: np.ndarray) -> np.ndarray:
        """(parameters, rows): the Jacobian transposed, the layout MINPACK keeps (``col_deriv``)."""
        key = z.tobytes()
        if key in self._last:  # the optimiser's shape check asks for the Jacobian at the start point first
            return self._last[key]
        # Forward differences with absolute steps (MINPACK's are relative to |z|). A parameter that
        # moves one channel only (a bias, a gain, a lever arm, gravity) leaves the other channel's
        # rows, every ridge row but its own and, unless it is gravity, the magnitude row exactly as
        # they were (gravity, a tilt and a magnitude when that row is there, moves its three ridge
        # rows): their differences are zero, and only the rows it moves are computed (each the same
        # number the full residual gives, see predict_rows).
        model, n6 = self.model, self.n6
        f0 = self.fun(z).copy()
        J = np.zeros((z.size, f0.size))
        f0r = f0[:n6].reshape(self.n, 6)
        for i in range(z.size):
            zp = z.copy()
            zp[i] += 0.01
            cols = _CHANNEL_OF.get(model.effect_of[i])
            if cols is None:
                J[i] = (self.fun(zp) - f0) / 0.01
                continue
            x = self.var.x(zp)
            p = model.params(x)
            J[i, :n6].reshape(self.n, 6)[:, cols] = (model.rows(p, cols) - f0r[:, cols]) / 0.01
            if self.var.sphere is not None and model.effect_of[i] == "gravity":
                J[i, n6:] = (np.concatenate(self.extra(zp, x, p)) - f0[n6:]) / 0.01
            else:
                J[i, n6 + i] = (self.ridge * (zp[i] - 1.0) - f0[n6 + i]) / 0.01
        self._last.clear()
        self._last[key] = J
        return J


#: The residual columns each effect moves when it alone changes (absent: both channels, or the
#: measurement itself, as a time offset does): a gravity change turns with the sensor but stays in
#: the specific force, and the lever arm only adds to the accelerometer.
_CHANNEL_OF: dict[str, slice] = {
    "gyro_bias": slice(0, 3),
    "gyro_scale": slice(0, 3),
    "acc_bias": slice(3, 6),
    "acc_scale": slice(3, 6),
    "lever_arm": slice(3, 6),
    "gravity": slice(3, 6),
}


class _Rows:
    """The normalised residual of one fit on its samples (:func:`normalized_residual` restricted to
    ``index``), with the model's stages and the shifted measurements kept between evaluations.

    Every number is computed by the operations :func:`normalized_residual` uses, sample by sample,
    so the rows are the same to the last bit; what the caches save is recomputing the stages a
    parameter change does not reach (:func:`~bodyschema.discrepancy.effects.predict_rows`).
    """

    def __init__(self, prob: Problem, fixed: Params, free: Sequence[str], index: np.ndarray) -> None:
        self.prob, self.fixed, self.free, self.index = prob, fixed, list(free), index
        #: the effect of every entry of the packed parameter vector
        self.effect_of = [n for n in self.free for _ in range(EFFECTS[n].size)]
        self.stages: dict = {}
        self._meas: dict[float, np.ndarray] = {}

    def params(self, x: np.ndarray) -> Params:
        p = dict(self.fixed)
        p.update(unpack(x, self.free))
        return p

    def _measured(self, seconds: float) -> np.ndarray:
        hit = self._meas.pop(seconds, None)
        if hit is None:
            hit = self.prob.measured_rows(seconds, self.index)
        self._meas[seconds] = hit  # the base point's offset and the one of the column at hand
        while len(self._meas) > 2:
            del self._meas[next(iter(self._meas))]
        return hit

    def rows(self, params: Mapping[str, Mapping[str, object]], cols: slice = slice(0, 6)) -> np.ndarray:
        """(len(index), columns) normalised residual of ``params``, the channel ``cols`` or both."""
        tau = 0.0
        if "time_offset" in params:
            tau = float(EFFECTS["time_offset"].from_params(params["time_offset"])[0])
            params = {k: v for k, v in params.items() if k != "time_offset"}
        gp, ap = predict_rows(self.prob.ref, params, self.index, self.stages)
        meas = self._measured(tau)
        scale = self.prob.scale
        if cols == slice(0, 3):
            return (meas[:, :3] - gp) / scale[0]
        if cols == slice(3, 6):
            return (meas[:, 3:] - ap) / scale[1]
        r = meas - np.concatenate([gp, ap], axis=1)
        r[:, :3] /= scale[0]
        r[:, 3:] /= scale[1]
        return r


class _Variables:
    """The optimiser's variables ``z`` of one fit and the parameter vector ``x`` they stand for.

    ``z = 1 + (x - null) / typical``, except gravity's three entries when ``pinned`` (the fit's free
    effects, given when gravity's magnitude is pinned): those are its tilt and magnitude
    (:class:`_Sphere`).
    """

    def __init__(self, null: np.ndarray, typical: np.ndarray, pinned: Sequence[str] | None) -> None:
        self.null, self.typical = null, typical
        self.sphere = None
        if pinned is not None:
            k = sum(EFFECTS[n].size for n in pinned[: list(pinned).index("gravity")])
            self.sphere = _Sphere(null[k : k + 3], typical[k : k + 3], k)

    def x(self, z: np.ndarray) -> np.ndarray:
        x = self.null + (z - 1.0) * self.typical
        if self.sphere is not None:
            x[self.sphere.at] = self.sphere.to_vector(z[self.sphere.at])
        return x

    def z(self, x: np.ndarray) -> np.ndarray:
        z = 1.0 + (x - self.null) / self.typical
        if self.sphere is not None:
            z[self.sphere.at] = self.sphere.from_vector(x[self.sphere.at])
        return z

    def deviation(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``(x - null) / typical`` of the variables ``z`` (standing for ``x``): the ridge pulls on
        the parameters themselves, gravity's vector too, whatever the optimiser's variables."""
        if self.sphere is None:
            return z - 1.0
        at = self.sphere.at
        d = z - 1.0
        d[at] = (x[at] - self.null[at]) / self.typical[at]
        return d


class _Sphere:
    """Gravity as a tilt and a magnitude, the optimiser's variables while the magnitude is pinned.

    ``w = 1 + (g0 * t1, g0 * t2, |g| - g0) / typical``, with ``(t1, t2)`` the tangent vector (radians)
    that turns the reference's gravity ``g_ref`` (magnitude ``g0``) into the direction of ``g``. Near
    ``g_ref`` these are the Cartesian deviations in the same units; what changes is the pin of
    :func:`_pinned_gravity`, linear in the magnitude here. On the Cartesian vector it is a sphere
    held to a few mm/s² by a stiff weight, and a Gauss-Newton step along the sphere's tangent rises
    off it by (step)² / 2 g0: on a translation trial with a tilted gravity Levenberg-Marquardt crawled
    along the sphere in steps of ~0.04 m/s², where the pin's rise ate what the step gained (30-40
    iterations to tilt gravity by 0.8 m/s²; 3-4 in these variables). The objective is the same
    function of the gravity vector either way, and so is its minimum.
    """

    def __init__(self, g_ref: np.ndarray, typical: np.ndarray, at: int) -> None:
        self.g0 = float(np.linalg.norm(g_ref))
        self.e = np.asarray(g_ref, dtype=np.float64) / self.g0
        # two unit vectors across e: the axis least along it, made orthogonal, and their cross product
        a = np.zeros(3)
        a[int(np.argmin(np.abs(self.e)))] = 1.0
        e1 = a - (a @ self.e) * self.e
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.e, self.e1)
        self.typical = np.asarray(typical, dtype=np.float64)
        self.at = slice(at, at + 3)

    def to_vector(self, w: np.ndarray) -> np.ndarray:
        """The gravity vector of the variables ``w`` (the sphere's exponential map at ``g_ref``)."""
        d = (w - 1.0) * self.typical
        t = (d[0] * self.e1 + d[1] * self.e2) / self.g0
        th = float(np.linalg.norm(t))
        return (self.g0 + d[2]) * (np.cos(th) * self.e + np.sinc(th / np.pi) * t)

    def from_vector(self, g: np.ndarray) -> np.ndarray:
        """The variables of the gravity vector ``g`` (inverse of :meth:`to_vector`)."""
        mag = float(np.linalg.norm(g))
        u = np.asarray(g, dtype=np.float64) / mag if mag > 0.0 else self.e
        across = u - (u @ self.e) * self.e
        s = float(np.linalg.norm(across))
        th = float(np.arctan2(s, u @ self.e))
        t = across * (th / s) if s > 0.0 else np.zeros(3)
        d = np.array([self.g0 * (t @ self.e1), self.g0 * (t @ self.e2), mag - self.g0])
        return 1.0 + d / self.typical


def _pin_row(params: Params, pin: tuple[float, float]) -> np.ndarray:
    """The row that holds the magnitude of the fitted gravity (:func:`_pinned_gravity`)."""
    g = np.asarray(params["gravity"]["vector"], dtype=np.float64)
    return np.array([pin[1] * (np.linalg.norm(g) - pin[0])])


#: How closely the magnitude of gravity is held to the reference's when an accelerometer scale is in
#: the model (m/s²): a tenth of the spread of local gravity over the Earth (9.78-9.83 m/s²).
_GRAVITY_MAGNITUDE_STD = 0.005

#: The accelerometer effects that can carry a difference in the magnitude of gravity.
_CARRY_MAGNITUDE = ("acc_scale", "acc_bias")


def _pinned_gravity(prob: Problem, free: Sequence[str], fixed: Params, n: int) -> tuple[float, float] | None:
    """``(magnitude, weight)`` of the row that holds the fitted gravity's magnitude at the
    reference's, or None when it stays free.

    An accelerometer scale common to the three axes and the magnitude of gravity make the same
    residual wherever the body is slow (the reading at rest is the scale times gravity), and so do an
    accelerometer bias along the vertical and the magnitude where the body hardly turns: with both
    free the fit trades one for the other along a valley the data barely see (on a slow BROAD trial
    it went to a scale of 0.92 and a gravity of 10.7 m/s², on a translation trial to a bias of 0.5
    m/s² and 9.36 m/s²). Local gravity is known far better than an accelerometer's scale or bias, so
    when either is in the model the magnitude is held, to :data:`_GRAVITY_MAGNITUDE_STD`, and the
    gravity effect is a tilt (fitted as one, :class:`_Sphere`). Alone, gravity keeps its
    magnitude free (a reference assuming 9.81 m/s² where it is 9.78 m/s²; the sensor networks'
    Eq. 11 case, where all of it is missing).
    """
    g0 = float(np.linalg.norm(prob.ref.gravity))
    if "gravity" not in free or g0 == 0.0 or not any(n in free or n in fixed for n in _CARRY_MAGNITUDE):
        return None
    # a deviation of one std costs as much as the whole residual's mean square
    return g0, float(np.sqrt(6 * n)) / _GRAVITY_MAGNITUDE_STD


def jacobian(
    prob: Problem, params: Mapping[str, Mapping[str, object]], names: Sequence[str]
) -> tuple[np.ndarray, np.ndarray]:
    """``(columns (T, 6, p), base residual (T, 6))``: how the normalised *prediction* moves per parameter.

    Finite differences around ``params`` (each effect's step is a tenth of its typical size). The
    columns are the residual signatures: regressing a residual on an effect's columns says how much
    of it that effect explains.
    """
    base_p = {k: dict(v) for k, v in params.items()}
    for n in names:
        base_p.setdefault(n, EFFECTS[n].to_params(nominal(n, prob.ref)))
    base = normalized_residual(prob, base_p)
    cols = []
    for n in names:
        e = EFFECTS[n]
        x = e.from_params(base_p[n])
        h = 0.1 * e.typical
        for i in range(e.size):
            xp = x.copy()
            xp[i] += h
            p = dict(base_p)
            p[n] = e.to_params(xp)
            cols.append((base - normalized_residual(prob, p)) / h)
    J = np.stack(cols, axis=2) if cols else np.zeros((*base.shape, 0))
    return J, base
