"""Beyond topology: each joint's axis and each IMU's lever arm, from gyros, accelerometers and encoders.

The topology (:mod:`bodyschema.estimate`) says which joint moves each IMU's link and which joint hangs
under which. Given that tree, the geometry follows from linear least squares on the same band-limited
signals the fast estimator compares (:mod:`bodyschema.timing`: encoders moved onto IMU time by the
estimated lag, every signal and every regressor through one low-pass band, so that linear models stay
exact sample by sample).

**Axis.** A revolute joint turns its child link about the unit axis ``u`` (child IMU frame) by ``q``.
With ``ω_p`` the parent link's angular velocity (parent IMU frame) and ``R0`` the rotation from the
parent IMU frame into the child IMU frame at ``q = 0``, the child gyro reads::

    ω_c = Rot(u, -q) R0 ω_p + u q̇ + b
        = A ω_p + B ω_p cos q + C ω_p sin q + a q̇ + b,
    A = u uᵀ R0,  B = (I - u uᵀ) R0,  C = -[u]× R0,  a = u

(``b`` the gyro bias). The model is linear in (A, B, C, a, b): one least-squares fit per gyro axis.
``u = a / |a|`` (``|a|`` is the gyro's gain along the axis), ``A + B = R0`` on the directions the
parent link turned about, and ``R0ᵀ u`` is the axis in the parent IMU's frame. A root joint on the
fixed base has ``ω_p = 0``: ``ω_c = a q̇ + b``. The regressor ``ω_p`` is the parent's angular
velocity rebuilt from the encoders (below), so neither gyro's bias nor gain enters it.

**Lever arm.** The child IMU sits at ``r`` from the foot ``o`` of its perpendicular on the axis. With
the link's angular velocity ``ω`` and acceleration ``α`` (child IMU frame), its specific force is::

    f_c = f_o + [α]× r + [ω]×[ω]× r

Moving ``o`` along the axis changes nothing but ``r``'s component along it, so that component is
unobservable from one joint and ``r`` is solved in the plane perpendicular to ``u`` (the *lever
arm*). ``f_o`` is what a point on the axis feels:

* root joint, fixed base: gravity seen from the turning frame plus the accelerometer bias,
  ``f_o = G0 + G1 cos q + G2 sin q`` (three unknown constant vectors; they absorb the accelerometer's
  gains too);
* otherwise, from the parent IMU ``p`` with ``d`` the position of ``o`` in its frame (the joint
  origin): ``f_o = R(q) (f_p + [α_p]× d + [ω_p]×[ω_p]× d)`` with the rotation ``R(q) = Rot(u, -q) R0``,
  plus first-order corrections for the two accelerometers' gains and intercepts ``b0 + b1 cos q + b2
  sin q`` for their biases seen through the joint (:func:`.lever_child`).

``ω`` and ``α`` are not read from the gyro: it is biased by up to tens of °/s and its gain is off by a
few %, and a lever arm scales with it. They are rebuilt down the tree from the encoders with the
fitted axes and rotations, ``ω_c = Rot(u, -q) R0 ω_p + u q̇`` (``ω = u q̇`` under a root joint), and
``α`` is their band-limited derivative. The tangential terms ``[α]× r`` (and ``[α_p]× d``) get lever
arms of their own and ``r`` (and ``d``) are read from the centripetal terms, which need ``ω`` alone: a
gain error of the differentiated ``α`` (a filter mismatch; or a simulator whose accelerometer follows
its forward-dynamics acceleration while its implicit integrator moves the joints slightly
differently) would otherwise scale the lever arm.

**The accelerometer's frame.** The gyro reads ``S ω`` with a sensitivity matrix ``S`` (gains within
3 %, cross-axis terms within 2 % on an MPU-6050), so the axis it reports, ``S u``, leans by up to about
two degrees, and the gyro alone cannot tell that from its mounting. The accelerometer can: gravity
turns with the link about the true axis, in the accelerometer's own frame, whose axes are square
(only its gains are off, and they are fitted). So the accelerometer model is refitted with the axis
free to lean (and, under a non-root joint, ``R0`` free to turn): nonlinear least squares over those
angles with the linear parameters projected out (:func:`.refine`), with its sandwich covariance. That
lean is fused with the gyro's reading, whose prior covariance follows from the datasheet bounds
(:func:`._gyro_lean_cov`), by inverse covariances (:func:`.fuse`): where the accelerometer sees the axis
well (gravity turns a lot about it) the answer is the accelerometer frame's, where it does not (an axis
near vertical) it stays near the gyro's with the gyro's uncertainty. The angular velocities rebuilt for
the joints below are then in the accelerometer's frame too. ``gyro_axis`` keeps the gyro's reading.

**The gyros' reading, for drift.** Each IMU's gyro is also regressed on its parent IMU's gyro as that
reads (:func:`.gyro_reading`), with the intercepts the parent gyro's bias needs through the joint and
one regressor for the encoder's steps at reversals (a dead band, :func:`._band_side`): ``gyro_axis``,
``gyro_axis_in_parent`` and ``backlash_deg`` then depend on two gyros' sensitivity matrices, which the
same IMUs repeat, and on noise, where the answers above carry every ancestor's, with errors that move
with the motion.

**Uncertainty.** The residuals of band-limited signals are autocorrelated, so the covariance of every
fit is the heteroscedasticity-and-autocorrelation-consistent (Newey-West) sandwich, with a Bartlett
window as long as the band's correlation time. ``axis_std_deg`` is the RMS angular error of ``u``: noise
and what remains of the gyro's lean after the fusion; ``gyro_axis_std_deg`` is the noise of the gyro's
reading alone (its lean is the same in every recording of one IMU, which is what drift compares).
``lever_arm_std_m`` is the RMS error of ``r``. What the sandwich cannot know, a model error of the
accelerometers' lean that does not shrink with more data, is added to their lean before the fusion
(``KinematicsOptions.acc_model_error_deg``, measured on simulated trees: :func:`.fuse`);
``bodyhealth bench kinematics`` reports the share of axes within two stds. An answer is ``converged``
when the joint moved enough, the axis gain is plausible and both stds (the gyro's noise and the lever
arm's) are within :class:`KinematicsOptions` bounds.

**What one recording leaves open.** Three answers, not two: a quantity the data do not fix is reported
with its std and named in ``undetermined``, with the motion that would fix it, not given as a number
that looks like the others. Where the parent link turned about one axis only (a root joint on the fixed
base), the child's ``R0`` turned about that axis's image fits exactly as well with ``d`` turned with
it: the parent's link accelerations ``K_p`` commute with turns about its own axis, so ``Rot R0`` and
``Rot d`` predict the same specific force. Only gravity across that axis tells the turn, ``g sin β``
for an axis ``β`` from vertical, and the accelerometers' biases trade with it (0.17 m/s² a degree
against their ±80 mg). The std of that turn comes from a fit over it alone, priors included
(:func:`._turn_std`); above ``max_axis_std_deg`` the turn, ``rotation_from_parent``,
``joint_origin_in_parent`` and the joint's ``axis_in_parent`` about that axis are undetermined. Such a
std is a curvature, not a bound: wells half a turn apart fit alike, and the rotations it flags can be
off by up to a half turn (``bodyhealth bench rotations`` compares the flagged and the passed ones with
the simulator on every catalog robot). Likewise two gyros on a link
that turned about one axis do not fix their rotation about it (:class:`SameLink`, ``rank``): the
joint's axis in the second one's frame is then left out.

Example
-------
>>> import numpy as np
>>> from bodyschema.recording import Recording
>>> from bodyschema.topology import Topology
>>> t = np.arange(3000) / 100.0
>>> q = np.c_[0.8 * np.sin(1.3 * t) + 0.4 * np.sin(3.1 * t)]
>>> qd = np.gradient(q[:, 0], t)
>>> u = np.array([0.0, 0.6, 0.8])
>>> gyro = (u * qd[:, None])[:, None, :]
>>> rec = Recording(t=t, joint_names=["j1"], q=q, imu_names=["imu1"], gyro=gyro,
...                 acc=np.zeros((3000, 1, 3)))
>>> k = estimate_kinematics(rec, Topology({"j1": None}, {"imu1": "j1"})).imus["imu1"]
>>> np.round(k.axis, 3).tolist(), bool(k.gyro_axis_std_deg < 0.1)
([0.0, 0.6, 0.8], True)

An accelerometer that reads nothing cannot tell the gyro's lean: the axis keeps the gyro's datasheet
uncertainty (MPU-6050: about a degree).

>>> bool(0.5 < k.axis_std_deg < 1.5)
True
"""

from __future__ import annotations

from bodyschema.kinematics.results import (
    UNOBSERVABLE,
    ImuKinematics,
    JointKinematics,
    Kinematics,
    KinematicsOptions,
    SameLink,
)
from bodyschema.kinematics.walk import estimate_kinematics
from bodyschema.rigid_motion import project_rotation, rotation_about

__all__ = [
    "UNOBSERVABLE",
    "ImuKinematics",
    "JointKinematics",
    "Kinematics",
    "KinematicsOptions",
    "SameLink",
    "estimate_kinematics",
    "project_rotation",
    "rotation_about",
]
