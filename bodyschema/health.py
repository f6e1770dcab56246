"""Signal health of one recording window: which sensors still report, and which joints really move.

The topology estimators answer "which joint does this IMU depend on"; they cannot tell a dead sensor
from a moved one, nor a locked joint from a frozen encoder, because all of these look like "no
dependency". This module looks at the raw signals to make those calls:

* **IMUs** — ``silent`` (expected but absent from the window), ``zero`` (reports exact zeros; a real
  accelerometer reads about 9.81 m/s² at rest), ``frozen`` (repeats the same sample), else ``ok``.
* **Joints** — the encoder's excitation (RMS joint velocity) and, when the layout puts IMUs on the
  joint's child link, the *relative motion* of that link against its parent link, measured from the
  gyros alone. For a rigid connection (joint not turning) the child gyro is a constant linear map of
  the parent gyro plus a bias; for a revolute joint it is exactly linear in ``[ω_p, ω_p·cos q,
  ω_p·sin q, q̇]`` (Rodrigues' formula in the link frames). The first fit's residual is the motion of
  the link relative to its parent; how much of it the encoder explains tells a frozen or wrong encoder
  (link turns, encoder does not agree) from a locked joint (neither turns).

A multi-rate window (encoders on their own stamps, docs/recording-format.md) is judged per stream:
IMUs on their own samples; joints on :func:`bodyschema.alignment.one_clock`, the encoder stream moved
onto the IMU's time by the lag the estimator found (``current.timing``) with velocities from the band-limited
differentiator of :mod:`bodyschema.timing` (central differences of 14-bit positions are mostly
quantization noise, and an uncorrected lag of a few ms reads as motion the encoder does not explain).

Everything here is pure numpy; thresholds are plain arguments so callers can tune them.

Example
-------
>>> import numpy as np
>>> from bodyschema.recording import Recording
>>> from bodyschema.topology import Topology
>>> t = np.arange(500) * 0.01
>>> q = np.c_[np.sin(t), 0.3 * np.sin(2 * t)]
>>> gyro = np.zeros((500, 2, 3))
>>> gyro[:, 0, 2] = np.cos(t)                                  # imu0 turns with j1 (z axis)
>>> gyro[:, 1, 2] = np.cos(t)                                  # imu1 rides j2 but j2 never turns it
>>> acc = np.random.default_rng(0).normal(0, 0.01, (500, 2, 3)) + [0, 0, 9.81]
>>> rec = Recording(t=t, joint_names=("j1", "j2"), q=q, imu_names=("imu0", "imu1"), acc=acc, gyro=gyro)
>>> layout = Topology({"j1": None, "j2": "j1"}, {"imu0": "j1", "imu1": "j2"})
>>> h = signal_health(rec, layout)
>>> h.joints["j1"].state, h.joints["j2"].state
('ok', 'unfollowed')
>>> h.imus["imu0"].state
'ok'
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bodyschema.alignment import one_clock
from bodyschema.hinge import hinge_design
from bodyschema.joint_motion import on_imu_clock, relative_motion, still_lately, still_since
from bodyschema.lstsq import scaled_lstsq
from bodyschema.recording import Recording
from bodyschema.topology import Topology

__all__ = [
    "IMU_STATES",
    "JOINT_STATES",
    "BaselineFingerprints",
    "HealthThresholds",
    "ImuFingerprint",
    "ImuHealth",
    "JointFingerprint",
    "JointHealth",
    "SignalHealth",
    "baseline_fingerprints",
    "fingerprints",
    "imu_fingerprints",
    "imu_health",
    "loose_imus",
    "relative_motion",
    "signal_health",
]

#: ``ok`` reports a live signal; the others mean the sensor is dead.
IMU_STATES: tuple[str, ...] = ("ok", "silent", "zero", "frozen")

#: ``ok``: encoder and link agree and move; ``still``: neither moves; ``frozen_encoder``: the link turns
#: but the encoder is flat; ``wrong_encoder``: both move but the encoder does not explain the link;
#: ``shifted_encoder``: both agree within the window but no longer as they did on the baseline (a
#: constant offset, with a :class:`JointFingerprint`); ``unfollowed``: the encoder moves but the link
#: does not turn with it; ``moving``/``flat``: only the
#: encoder could be judged (no healthy IMU on the child link).
JOINT_STATES: tuple[str, ...] = (
    "ok",
    "still",
    "frozen_encoder",
    "wrong_encoder",
    "shifted_encoder",
    "unfollowed",
    "moving",
    "flat",
)


@dataclass(frozen=True)
class HealthThresholds:
    """Decision thresholds (units in the names).

    ``excitation_rad_s``: RMS joint velocity above which an encoder counts as moving.
    ``motion_rad_s``: RMS relative angular rate above which a link counts as turning against its parent.
    ``explained``: fraction of that relative motion the encoder must explain to count as consistent.
    ``frozen_fraction``: share of repeated consecutive samples that makes an IMU frozen.
    ``zero_abs``: readings below this magnitude (both acc and gyro) count as zero.
    ``repeat_abs``: consecutive readings closer than this count as one repeated sample: far below one
    LSB of any 16-bit IMU (MPU-6050: 1.3e-4 rad/s, 6e-4 m/s² at the finest range) and far above the
    round-off that resampling or filtering a frozen output leaves.
    ``min_samples``: fewer samples than this and nothing is judged.
    ``max_pairs``: IMUs per link used for the relative-motion fits (each side).
    ``shift_ratio``/``shift_rad_s``: a baseline fingerprint that leaves more than ``shift_ratio`` times
    the window's own residual, and more than ``shift_rad_s`` RMS, marks a shifted encoder.
    ``loose_false_alarm``: the chance, per IMU and window, that a firmly mounted IMU reads as loose
    (:func:`loose_imus`: the tolerance follows from it and the window's degrees of freedom).
    ``lock_seconds``: a joint whose encoder and link have both been still this long, to the end of the
    window, does not move now (a policy: the worker's cycle interval, so two cycles see it).
    ``still_rad``/``still_seconds``: an encoder whose last ``still_seconds`` or more stay within ``still_rad``
    of its last reading is still *now*; the default is two steps of the coarsest encoder of docs/design.md,
    'Facts the error models use' (12 bits per turn), so quantization flicker of a held joint stays inside it.
    A link turning against its parent at ``motion_rad_s`` covers 0.05 rad in a second, sixteen times
    ``still_rad``: an encoder that stays still that long while the gyros see such motion contradicts them.
    ``stop_margin_s``: how long after an encoder stops, on the IMU's clock, its gyros may still show the
    motion: the IMU's low-pass settles within about four group delays (a 44 Hz DLPF: 4.8 ms each,
    about 20 ms), and the estimated lag it is mapped with is good to a few ms; 50 ms covers both
    twice. Without it the last few ms of a joint stopping at 1 rad/s read, over a still second, as a
    link turning against a still encoder.
    """

    excitation_rad_s: float = 0.05
    motion_rad_s: float = 0.05
    explained: float = 0.8
    frozen_fraction: float = 0.9
    zero_abs: float = 1e-6
    repeat_abs: float = 1e-6
    min_samples: int = 20
    max_pairs: int = 3
    shift_ratio: float = 3.0
    shift_rad_s: float = 0.05
    still_rad: float = 2 * 2 * np.pi / 4096
    still_seconds: float = 1.0
    lock_seconds: float = 5.0
    loose_false_alarm: float = 1e-9
    stop_margin_s: float = 0.05


@dataclass(frozen=True)
class ImuHealth:
    """One IMU in one window: ``state`` in :data:`IMU_STATES`, ``gyro_rms`` (rad/s, mean removed)."""

    name: str
    state: str
    gyro_rms: float = 0.0

    @property
    def dead(self) -> bool:
        return self.state != "ok"


@dataclass(frozen=True)
class JointHealth:
    """One joint in one window.

    ``excitation``: RMS encoder velocity (rad/s). ``relative_motion``: RMS angular rate of the child link
    against its parent link (rad/s; None when no healthy IMU rides the child link). ``explained``:
    fraction of that motion the encoder accounts for (None when not judged). ``state`` in
    :data:`JOINT_STATES`.
    """

    name: str
    state: str
    excitation: float
    relative_motion: float | None = None
    explained: float | None = None

    @property
    def encoder_moving(self) -> bool:
        return self.state in ("ok", "wrong_encoder", "shifted_encoder", "unfollowed", "moving")

    @property
    def link_moving(self) -> bool | None:
        if self.relative_motion is None:
            return None
        return self.state in ("ok", "frozen_encoder", "wrong_encoder", "shifted_encoder")


@dataclass(frozen=True)
class SignalHealth:
    """Health of every expected IMU and every joint of one window."""

    imus: dict[str, ImuHealth] = field(default_factory=dict)
    joints: dict[str, JointHealth] = field(default_factory=dict)
    #: IMUs that follow their link more loosely than on the baseline, with the growth of their
    #: residual share (:func:`loose_imus`); empty without IMU fingerprints.
    loose: dict[str, float] = field(default_factory=dict)

    @property
    def dead_imus(self) -> list[str]:
        return sorted(n for n, h in self.imus.items() if h.dead)

    @property
    def moving_joints(self) -> list[str]:
        """Joints whose encoder or child link moves."""
        return sorted(n for n, h in self.joints.items() if h.encoder_moving or h.link_moving)

    @property
    def body_moving(self) -> bool:
        return bool(self.moving_joints)

    def to_json(self) -> dict[str, Any]:
        def r(x: float | None) -> float | None:
            return None if x is None else round(float(x), 6)

        return {
            "imus": {n: {"state": h.state, "gyro_rms": r(h.gyro_rms)} for n, h in self.imus.items()},
            "joints": {
                n: {
                    "state": h.state,
                    "excitation": r(h.excitation),
                    "relative_motion": r(h.relative_motion),
                    "explained": r(h.explained),
                }
                for n, h in self.joints.items()
            },
            **({"loose": {n: r(v) for n, v in self.loose.items()}} if self.loose else {}),
        }


# ---------------------------------------------------------------------------------------------- IMUs
def imu_health(
    acc: np.ndarray, gyro: np.ndarray, name: str = "", thresholds: HealthThresholds | None = None
) -> ImuHealth:
    """Judge one IMU from its ``(T,3)`` accelerometer and gyro series.

    >>> import numpy as np
    >>> imu_health(np.zeros((50, 3)), np.zeros((50, 3)), "a").state
    'zero'
    >>> imu_health(np.tile([0, 0, 9.8], (50, 1)), np.tile([0.1, 0, 0], (50, 1)), "b").state
    'frozen'
    """
    th = thresholds or HealthThresholds()
    if acc.shape[0] == 0:
        return ImuHealth(name, "silent")
    both = np.concatenate([acc, gyro], axis=1)
    gyro_rms = float(np.sqrt(np.mean(np.sum((gyro - gyro.mean(axis=0)) ** 2, axis=1))))
    zero = np.all(np.abs(both) < th.zero_abs, axis=1)
    if zero.all() or _trailing(zero) >= th.min_samples:
        return ImuHealth(name, "zero", gyro_rms)
    if both.shape[0] >= 2:
        repeated = np.all(np.abs(np.diff(both, axis=0)) <= th.repeat_abs, axis=1)
        if float(np.mean(repeated)) >= th.frozen_fraction or _trailing(repeated) >= th.min_samples:
            return ImuHealth(name, "frozen", gyro_rms)
    return ImuHealth(name, "ok", gyro_rms)


def _trailing(flags: np.ndarray) -> int:
    """Length of the run of True at the end of ``flags``.

    A sensor that died mid-window is dead *now*: its last samples are zeros or one repeated sample, while the
    window as a whole is still mostly live. A live MEMS IMU's noise (a few LSB RMS on every axis,
    docs/design.md, 'Facts the error models use') makes two equal consecutive six-axis samples rare and
    ``min_samples`` in a row impossible, so a trailing run that long is a dead sensor however short a part of
    the window it is; judging the share of the whole window instead would call the IMU alive until the window
    is mostly dead, and meanwhile the estimator, seeing it follow nothing, would report it detached.

    >>> _trailing(np.array([True, False, True, True])), _trailing(np.array([True, False]))
    (2, 0)
    """
    off = np.flatnonzero(~flags)
    return int(flags.shape[0] - (off[-1] + 1 if off.size else 0))


# -------------------------------------------------------------------------------------------- joints


@dataclass(frozen=True)
class JointFingerprint:
    """How one joint's encoder related to its child IMU's gyro on a healthy window.

    ``coef`` maps the regressors ``[ω_ref, ω_ref·cos q, ω_ref·sin q, q̇, 1]`` (``ref`` None: the parent
    link is the fixed base, ``[q̇, 1]``) to the gyro of IMU ``child``. Within one window a constant
    encoder offset is invisible (``cos(q + c)`` is a mix of ``cos q`` and ``sin q``); against the
    fingerprint it is not.
    """

    joint: str
    child: str
    ref: str | None
    coef: np.ndarray


def fingerprints(
    rec: Recording,
    layout: Topology,
    current: Topology | None = None,
    thresholds: HealthThresholds | None = None,
) -> dict[str, JointFingerprint]:
    """Fingerprints of the joints of ``rec`` whose encoder and child link agree (state ``ok``), each
    from the best-fitting child/reference IMU pair; learn them on the window the baseline came from."""
    health = signal_health(rec, layout, current=current, thresholds=thresholds)
    th = thresholds or HealthThresholds()
    rec = d = one_clock(rec, current)
    assert d.q is not None and d.qd is not None
    present = {n: k for k, n in enumerate(rec.imu_names)}
    out: dict[str, JointFingerprint] = {}
    for j, jh in health.joints.items():
        if jh.state != "ok":
            continue
        child, parent = _pairs(j, layout, health, present, current, th)
        k = rec.joint_names.index(j)
        best: tuple[float, JointFingerprint] | None = None
        for c in child:
            Y = rec.gyro[:, present[c], :]
            for p in parent or [None]:
                X = hinge_design(None if p is None else rec.gyro[:, present[p], :], d.q[:, k], d.qd[:, k])
                coef = scaled_lstsq(X, Y).coef
                res = float(np.mean((Y - X @ coef) ** 2))
                if best is None or res < best[0]:
                    best = (res, JointFingerprint(j, c, p, coef))
        if best is not None:
            out[j] = best[1]
    return out


@dataclass(frozen=True)
class ImuFingerprint:
    """How tightly one IMU followed its link on a healthy window, next to the other IMUs of the link.

    ``share`` is its residual variance under the exact one-joint gyro model of :func:`relative_motion`
    (joint ``joint``, reference gyro ``ref`` on the parent link, None = the fixed base) divided by the
    median of the same for its siblings, the other IMUs of the link. Every IMU of a link sees the same
    motion, so whatever the motion leaves in the residual (timing error times angular acceleration,
    encoder quantization) cancels in the share; what remains is the IMU's own noise and mounting,
    constant while it stays firmly mounted.
    """

    imu: str
    joint: str
    ref: str | None
    share: float


def _link_residuals(
    d: Recording, present: dict[str, int], imus: list[str], joint: str, ref: str | None
) -> dict[str, float]:
    """Residual variance of each IMU of ``imus`` (one link, on ``joint``) under the one-joint model."""
    assert d.q is not None and d.qd is not None
    k = d.joint_names.index(joint)
    X = hinge_design(None if ref is None else d.gyro[:, present[ref], :], d.q[:, k], d.qd[:, k])
    out = {}
    for i in imus:
        Y = d.gyro[:, present[i], :]
        out[i] = float(np.mean((Y - X @ scaled_lstsq(X, Y).coef) ** 2))
    return out


def _links(
    layout: Topology, healthy: set[str], current: Topology | None
) -> list[tuple[str, list[str], str | None]]:
    """``(joint, IMUs of its link, reference IMU)`` for every link with two or more healthy IMUs that
    the current estimate still places there, and a trusted reference (or the base)."""
    out = []
    for j, pj in layout.joint_parent.items():
        imus = sorted(i for i, jj in layout.imu_joint.items() if jj == j and i in healthy)
        if current is not None:
            imus = [i for i in imus if current.imu_joint.get(i, "?") == j]
        if len(imus) < 2:
            continue
        if pj is None:
            out.append((j, imus, None))
            continue
        refs = sorted(i for i, jj in layout.imu_joint.items() if jj == pj and i in healthy)
        if current is not None:
            refs = [i for i in refs if current.imu_joint.get(i, "?") == pj]
        if refs:
            out.append((j, imus, refs[0]))
    return out


def _shares(residuals: dict[str, float]) -> dict[str, float]:
    """Each IMU's residual over the median of its siblings'."""
    out = {}
    for i, v in residuals.items():
        sib = float(np.median([w for n, w in residuals.items() if n != i]))
        out[i] = v / sib if sib > 0 else float("inf")
    return out


def imu_fingerprints(
    rec: Recording,
    layout: Topology,
    current: Topology | None = None,
    thresholds: HealthThresholds | None = None,
) -> dict[str, ImuFingerprint]:
    """The :class:`ImuFingerprint` of every IMU on a link with two or more healthy IMUs; learn them on
    a window that matches the baseline (as :func:`fingerprints`)."""
    th = thresholds or HealthThresholds()
    health = signal_health(rec, layout, current=current, thresholds=th)
    present = {n: k for k, n in enumerate(rec.imu_names)}
    healthy = {n for n, h in health.imus.items() if not h.dead and n in present}
    d = one_clock(rec, current)
    if d.q is None or d.n_samples < th.min_samples:
        return {}
    out = {}
    for j, imus, ref in _links(layout, healthy, current):
        for i, share in _shares(_link_residuals(d, present, imus, j, ref)).items():
            out[i] = ImuFingerprint(i, j, ref, share)
    return out


@dataclass(frozen=True)
class BaselineFingerprints:
    """What one healthy window on the baseline teaches: how each joint's encoder relates to its link
    (``joints``), and how tightly each IMU follows its link (``imus``)."""

    joints: dict[str, JointFingerprint]
    imus: dict[str, ImuFingerprint]


def baseline_fingerprints(
    rec: Recording,
    layout: Topology,
    current: Topology | None = None,
    thresholds: HealthThresholds | None = None,
) -> BaselineFingerprints:
    """:func:`fingerprints` and :func:`imu_fingerprints` of one window."""
    return BaselineFingerprints(
        fingerprints(rec, layout, current, thresholds), imu_fingerprints(rec, layout, current, thresholds)
    )


def loose_tolerance(n_samples: int, rate_hz: float, band_hz: float | None, false_alarm: float) -> float:
    """The largest growth of an IMU's residual share that a firmly mounted IMU shows by chance.

    Error model: each residual variance is a mean of squares over ``n_samples`` samples of three axes,
    correlated over ``rate_hz / (2 band_hz)`` samples when the gyro is low-passed to ``band_hz``, so it
    has ``n = 3 n_samples min(1, 2 band_hz / rate_hz)`` degrees of freedom and its logarithm a standard
    deviation of ``sqrt(2 / n)``. The growth compares four such estimates (the IMU and its siblings,
    now and on the baseline; the siblings' median counted as one), so its logarithm has a standard
    deviation of ``sqrt(8 / n)``; the tolerance is the one-sided normal quantile of ``false_alarm``
    times that.

    Assumed, not modelled: the residual is dominated by what the link's motion leaves (shared by the
    siblings) or the siblings' own noise is alike. When the shared part changes between windows and
    the siblings' own noise differs by a factor ``r``, a firm IMU's share can drift by up to ``r``
    (far below a tethered IMU's growth on the damage suite: docs/service.md).

    >>> round(loose_tolerance(3000, 100.0, None, 1e-9), 3)   # 30 s at 100 Hz, white residual
    1.196
    >>> round(loose_tolerance(3000, 100.0, 20.0, 1e-9), 3)   # the same low-passed to 20 Hz
    1.327
    """
    from scipy.stats import norm

    n = 3.0 * n_samples * (1.0 if band_hz is None else min(1.0, 2.0 * band_hz / rate_hz))
    return float(np.exp(norm.isf(false_alarm) * np.sqrt(8.0 / max(n, 1.0))))


def loose_imus(
    rec: Recording,
    fingerprints: dict[str, ImuFingerprint],
    healthy: set[str],
    current: Topology | None = None,
    thresholds: HealthThresholds | None = None,
) -> dict[str, float]:
    """IMUs that follow their link more loosely than on the baseline: ``imu -> growth`` of the residual
    share (:class:`ImuFingerprint`) beyond :func:`loose_tolerance`.

    A detached IMU on a short tether keeps turning with its link (it hangs from it), and over a window
    its gyro departs from the link's by a percent or two: inside what the topology estimators accept,
    so they still place it on its link. Against its own share on the baseline it stands out (about
    twice the variance, where a firm IMU's share varies by a percent between windows). Judged only for
    IMUs the current estimate places on their baseline link, with their reference and at least one
    sibling healthy; a window that straddles a change is not judged (the change shows there anyway).
    """
    th = thresholds or HealthThresholds()
    present = {n: k for k, n in enumerate(rec.imu_names)}
    return _loose(one_clock(rec, current), present, fingerprints, healthy, current, th)


def _loose(
    d: Recording,
    present: dict[str, int],
    fingerprints: dict[str, ImuFingerprint],
    healthy: set[str],
    current: Topology | None,
    th: HealthThresholds,
) -> dict[str, float]:
    """:func:`loose_imus` on the window ``d`` already on one clock."""
    if not fingerprints or d.q is None or d.n_samples < th.min_samples:
        return {}
    by_link: dict[tuple[str, str | None], list[str]] = {}
    for i, fp in fingerprints.items():
        placed = current is None or current.imu_joint.get(i, "?") == fp.joint
        ref_ok = fp.ref is None or (fp.ref in healthy and fp.ref in present)
        if i in healthy and i in present and placed and ref_ok:
            by_link.setdefault((fp.joint, fp.ref), []).append(i)
    rate = (d.n_samples - 1) / max(float(d.t[-1] - d.t[0]), 1e-9)
    band = (current.timing or {}).get("band_hz") if current is not None else None
    tol = loose_tolerance(d.n_samples, rate, band, th.loose_false_alarm)
    out = {}
    for (j, ref), imus in by_link.items():
        if len(imus) < 2:
            continue
        for i, share in _shares(_link_residuals(d, present, imus, j, ref)).items():
            growth = share / fingerprints[i].share
            if growth > tol:
                out[i] = growth
    return out


def _pairs(
    j: str,
    layout: Topology,
    health: SignalHealth,
    present: dict[str, int],
    current: Topology | None,
    th: HealthThresholds,
) -> tuple[list[str], list[str]]:
    """Healthy child-link IMUs and trusted parent-link IMUs of joint ``j`` (a few of each)."""
    healthy = {n for n, h in health.imus.items() if not h.dead and n in present}
    child = sorted(i for i, jj in layout.imu_joint.items() if jj == j and i in healthy)
    pj = layout.joint_parent[j]
    parent = sorted(i for i, jj in layout.imu_joint.items() if jj == pj and i in healthy)
    if current is not None:
        parent = [i for i in parent if current.imu_joint.get(i, "?") == pj] or parent
    return child[: th.max_pairs], parent[: th.max_pairs]


def _joint_state(
    excitation: float, motion: float | None, explained: float | None, th: HealthThresholds
) -> str:
    enc = excitation > th.excitation_rad_s
    if motion is None:
        return "moving" if enc else "flat"
    link = motion > th.motion_rad_s
    if enc and link:
        return "ok" if (explained or 0.0) >= th.explained else "wrong_encoder"
    if enc:
        return "unfollowed"
    if link:
        return "frozen_encoder"
    return "still"


# --------------------------------------------------------------------------------------------- whole
def signal_health(
    rec: Recording,
    layout: Topology | None = None,
    expected_imus: Iterable[str] | None = None,
    thresholds: HealthThresholds | None = None,
    current: Topology | None = None,
    fingerprints: dict[str, JointFingerprint] | None = None,
    imu_fingerprints: dict[str, ImuFingerprint] | None = None,
) -> SignalHealth:
    """Health of every IMU and joint in ``rec``.

    ``layout`` (usually the baseline topology) says which IMUs ride which link; without it joints are
    judged from their encoders alone. ``expected_imus`` (default: the layout's IMUs plus the
    recording's) names IMUs that should report; those absent from ``rec`` are ``silent``. ``current``
    (the estimate from the same window) picks the reference IMUs on each parent link: those it still
    places where the layout does, so a moved or loose IMU does not serve as the parent link.
    ``fingerprints`` (from :func:`fingerprints` on the baseline window) turn an ``ok`` joint whose
    encoder relates to its link differently than on the baseline into ``shifted_encoder``;
    ``imu_fingerprints`` (from :func:`imu_fingerprints`) name the IMUs that follow their link loosely
    (``loose``, :func:`loose_imus`).
    """
    th = thresholds or HealthThresholds()
    present = {n: k for k, n in enumerate(rec.imu_names)}
    expected = list(
        dict.fromkeys([*(expected_imus or ()), *((layout.imu_joint) if layout else ()), *rec.imu_names])
    )
    enough = rec.n_samples >= th.min_samples
    imus: dict[str, ImuHealth] = {}
    for name in expected:
        if name not in present or not enough:
            imus[name] = ImuHealth(name, "silent" if name not in present else "ok")
            continue
        k = present[name]
        imus[name] = imu_health(rec.acc[:, k, :], rec.gyro[:, k, :], name, th)

    joints: dict[str, JointHealth] = {}
    if rec.q is None or rec.n_joints == 0 or not enough:
        return SignalHealth(imus, joints)
    stopped = on_imu_clock(still_since(rec, th), rec, current)
    rec = d = one_clock(rec, current)  # IMUs were judged on their own stream above
    if d.n_samples < th.min_samples:
        return SignalHealth(imus, joints)
    assert d.qd is not None and d.q is not None
    healthy = {n for n, h in imus.items() if not h.dead and n in present}
    ctx = _Judging(d, present, healthy, layout, current, fingerprints or {}, stopped, th)
    for j_idx, j in enumerate(rec.joint_names):
        joints[j] = _joint_health(ctx, j_idx, j)
    loose = _loose(d, present, imu_fingerprints or {}, healthy, current, th)
    return SignalHealth(imus, joints, loose)


@dataclass(frozen=True)
class _Judging:
    """What :func:`signal_health` judges every joint against: the window on one clock, the IMUs in it
    and which of them are healthy, the layout and the current estimate, and the baseline's fingerprints."""

    d: Recording
    present: dict[str, int]
    healthy: set[str]
    layout: Topology | None
    current: Topology | None
    fingerprints: dict[str, JointFingerprint]
    still_since: np.ndarray
    th: HealthThresholds


def _joint_health(ctx: _Judging, j_idx: int, j: str) -> JointHealth:
    """Joint ``j``'s health: from its encoder alone, or against the IMUs on its link and its parent's."""
    d, th, layout = ctx.d, ctx.th, ctx.layout
    assert d.qd is not None
    excitation = float(np.sqrt(np.mean(d.qd[:, j_idx] ** 2)))
    if layout is not None and j in layout.joint_parent:
        child = sorted(i for i, jj in layout.imu_joint.items() if jj == j and i in ctx.healthy)
        parent_joint = layout.joint_parent[j]
        parent = sorted(i for i, jj in layout.imu_joint.items() if jj == parent_joint and i in ctx.healthy)
        if ctx.current is not None:
            trusted = [i for i in parent if ctx.current.imu_joint.get(i, "?") == parent_joint]
            parent = trusted or parent
        if child and (parent or parent_joint is None):
            return _joint_against_imus(ctx, j_idx, j, child, parent, excitation)
    return JointHealth(j, _joint_state(excitation, None, None, th), excitation)


def _joint_against_imus(
    ctx: _Judging, j_idx: int, j: str, child: list[str], parent: list[str], excitation: float
) -> JointHealth:
    """Joint ``j`` judged by how its child link's IMUs move against its parent link's."""
    d, th, present = ctx.d, ctx.th, ctx.present
    assert d.qd is not None and d.q is not None
    qd = d.qd[:, j_idx]
    # Several references and subjects (a few each, to bound the cost): one moved or loose
    # IMU on either link must not decide the joint. Per subject the reference that leaves
    # the least unexplained motion (full model residual) wins: a swinging reference fits
    # nothing, a rigid one fits a locked joint and a turning one alike.
    refs = [d.gyro[:, present[p], :] for p in parent[: th.max_pairs]] or [None]
    fits = [
        min(
            (relative_motion(d.gyro[:, present[c], :], pg, d.q[:, j_idx], qd) for pg in refs),
            key=lambda f: f[0] * np.sqrt(max(0.0, 1.0 - f[1])),
        )
        for c in child[: th.max_pairs]
    ]
    states = [_joint_state(excitation, m, e, th) for m, e in fits]
    # One IMU that agrees with the encoder clears the joint: a single moved or detached
    # IMU on the link must not read as an encoder fault.
    pick = (
        states.index("ok")
        if "ok" in states
        else max(range(len(states)), key=lambda k: (states.count(states[k]), fits[k][0]))
    )
    motion, explained = fits[pick]
    state = states[pick]
    if state not in ("frozen_encoder", "still"):
        late = still_lately(d, d, j_idx, ctx.still_since[j_idx], child, refs, present, th)
        if late is not None:
            state, excitation, motion, explained = late
    fp = ctx.fingerprints.get(j)
    if (
        state == "ok"
        and fp is not None
        and _shifted(fp, d, d, j_idx, present, ctx.healthy, ctx.layout, ctx.current, th)
    ):
        state = "shifted_encoder"
    return JointHealth(j, state, excitation, motion, explained)


def _shifted(
    fp: JointFingerprint,
    rec: Recording,
    d: Recording,
    k: int,
    present: dict[str, int],
    healthy: set[str],
    layout: Topology,
    current: Topology | None,
    th: HealthThresholds,
) -> bool:
    """Whether the fingerprint's pair, still in place, now needs a different encoder relation."""
    pair = [fp.child] + ([fp.ref] if fp.ref is not None else [])
    if any(p not in healthy for p in pair):
        return False
    if current is not None and (
        current.imu_joint.get(fp.child) != fp.joint
        or (fp.ref is not None and current.imu_joint.get(fp.ref) != layout.joint_parent[fp.joint])
    ):
        return False  # the pair moved: a placement finding, not an encoder one
    assert d.q is not None and d.qd is not None
    X = hinge_design(None if fp.ref is None else rec.gyro[:, present[fp.ref], :], d.q[:, k], d.qd[:, k])
    Y = rec.gyro[:, present[fp.child], :]
    if X.shape[1] != fp.coef.shape[0]:
        return False
    old = float(np.sqrt(np.mean((Y - X @ fp.coef) ** 2)))
    new = float(np.sqrt(np.mean((Y - X @ scaled_lstsq(X, Y).coef) ** 2)))
    return old > max(th.shift_ratio * new, th.shift_rad_s)
