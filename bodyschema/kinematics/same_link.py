"""Two IMUs on one link: the rotation between their frames, from their gyros."""

from __future__ import annotations

import math

import numpy as np

from bodyschema.kinematics.axis import span_axes, span_projector
from bodyschema.kinematics.least_squares import per_axis, variances
from bodyschema.kinematics.results import KinematicsOptions, SameLink
from bodyschema.kinematics.signals import Signals
from bodyschema.rigid_motion import project_rotation

__all__ = [
    "same_link_fit",
    "vec_text",
]


def same_link_fit(
    sig: Signals, a: int, b: int, names: tuple[str, ...], omega: np.ndarray, opts: KinematicsOptions
) -> SameLink | None:
    """``gyro_a = M gyro_b + bias``; the rotation is ``M`` projected, its noise std from M's
    off-diagonals, its std with the gyros' cross-axis errors too (:class:`SameLink`). Measured on the
    catalog robots (``bench rotations``), the rotations at rank 2 or more are off by about that.

    The rank is that of the link's angular velocity ``omega`` as the encoders rebuild it (``a``'s frame;
    no gyro noise in it, so a root joint's link has rank 1 however little it moved), directions below
    1 % of the strongest's power left out, as :func:`axis_fit` leaves out a measured parent's."""
    gb = sig.band_limit(sig.rec.gyro[:, b])
    ga = sig.band_limit(sig.rec.gyro[:, a])
    moving = gb - gb.mean(axis=0)
    if float(np.sqrt(np.mean(moving**2))) < 1e-3:
        return None
    X = np.c_[gb, np.ones(gb.shape[0])]
    coef, cov = per_axis(X, ga, sig.lags)
    M = coef[:3].T
    v = variances(cov)[:3].T
    off = float(np.sum(v) - np.sum(np.diag(v)))
    link = sig.band_limit(omega)
    rank, axis = span_axes(span_projector(link - link.mean(axis=0), 1e-2))
    noise = math.degrees(math.sqrt(off / 4.0))
    open_: tuple[str, ...] = ()
    std = math.hypot(noise, math.degrees(opts.gyro_cross_axis))
    if rank < 2:
        std = noise = math.inf
        open_ = (
            f"the turn about the link's one axis ({vec_text(axis)} in {names[a]}'s frame): the link "
            "turned about it only; a recording in which it turns about a second axis too (a joint above "
            "it, or the base, moving) fixes it",
        )
    return SameLink(
        a=names[a],
        b=names[b],
        rotation=project_rotation(M),
        std_deg=std,
        rank=rank,
        undetermined=open_,
        noise_std_deg=noise,
    )


def vec_text(v: np.ndarray) -> str:
    """A unit vector for a sentence: ``[0.00, 0.71, 0.71]``."""
    return "[" + ", ".join(f"{x:.2f}" for x in v) + "]"
