"""Can a point-footed robot's feet tell a 2° fault? The stance feet's plane against the IMU's gravity.

A point foot fixes no rotation, so the stance-chain and stance-tilt checks of
:mod:`bodyschema.floating_health` have nothing to predict the base IMU's gravity from. With the legs'
geometry (the URDF) one reference remains: on level ground three or more stance feet not on one line
span the floor, and its normal in the IMU frame is the gravity the accelerometer should read
(:func:`bodyschema.floating_base.foot_plane_gravity`). A 2° mount turn moves the accelerometer's gravity
by 2° against that plane; an encoder offset moves one foot and turns the plane by what the leg's
geometry makes of it.

Whether either can be seen depends on how much the tilt between the two moves on a healthy robot: the
base's own acceleration in the low-passed accelerometer, feet that sink or roll, and the gait
changing. None of it is white, so it is measured, not modelled: the tilt averaged over 1 s blocks
(their spread), and the change of the mean between the recording's two halves (what a baseline of one
half sees in the other). A fault is decidable here only when its shift of the mean clears that change.

This module measures; it raises nothing. Example (a log and its URDF, as ``bench robots`` reads them)::

    model = read_robot("go1.urdf", rec.joint_names)
    foot_plane_tilt(rec, model, ("imu_rotated:imu=trunk_imu,deg=2",))
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from bodyschema.contacts import force_contacts
from bodyschema.faults import inject, parse_fault
from bodyschema.floating_base import chain_frames, foot_plane_gravity
from bodyschema.recording import Recording
from bodyschema.rigid_motion import lowpass
from bodyschema.stance_chains import foot_forces
from sim2real.robots import RobotModel

__all__ = ["foot_plane_tilt"]

#: The accelerometer's gravity: the specific force low-passed below the trot's first harmonics (Hz).
CUTOFF_HZ = 5.0
#: Block length of the spread (s): a stride or more.
BLOCK_S = 1.0


def _tilt(rec: Recording, model: RobotModel, down: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(samples with a plane, (n, 2) small-angle tilt of the accelerometer's gravity from the plane's
    about the IMU's x and y axes, rad)."""
    feet = np.stack([chain_frames(ch, rec.q)[1] for ch in model.feet.values()], axis=1)  # positions only
    plane = foot_plane_gravity(feet, down, np.asarray(rec.gravity, float))
    ok = np.isfinite(plane[:, 0])
    measured = -lowpass(rec.acc[:, 0], rec.sample_rate, CUTOFF_HZ)[ok]
    a = plane[ok] / np.linalg.norm(plane[ok], axis=1, keepdims=True)
    b = measured / np.linalg.norm(measured, axis=1, keepdims=True)
    return ok, np.cross(a, b)[:, :2]


def foot_plane_tilt(rec: Recording, model: RobotModel, faults: Sequence[str]) -> dict[str, Any]:
    """The healthy tilt's spread and half-to-half change, and each fault's shift of its mean (degrees).

    Contacts come from the log's foot forces (:func:`bodyschema.contacts.force_contacts`); a robot with
    flat feet or without foot forces gets ``{"skipped": why}``.
    """
    if model.flat:
        return {"skipped": "flat feet: the stance-tilt check reads the foot itself"}
    forces, _ = foot_forces(rec)
    if forces is None or forces.shape[1] != len(model.feet):
        return {"skipped": "no foot force per foot: the stance feet are unknown"}
    down = force_contacts(forces, rec.sample_rate).down
    ok, tilt = _tilt(rec, model, down)
    t = rec.t[ok]
    half = rec.t[0] + rec.duration / 2
    first = t < half
    block = np.floor((t - rec.t[0]) / BLOCK_S).astype(int)
    means = np.array([tilt[block == b].mean(axis=0) for b in np.unique(block)])
    change = tilt[~first].mean(axis=0) - tilt[first].mean(axis=0)
    shifts = {}
    for spec in faults:
        _, moved = _tilt(inject(rec, parse_fault(spec)), model, down)
        shifts[spec] = float(np.degrees(np.linalg.norm(moved.mean(axis=0) - tilt.mean(axis=0))))
    return {
        "plane_fraction": round(float(ok.mean()), 3),
        "block_std_deg": np.degrees(means.std(axis=0, ddof=1)).round(2).tolist(),
        "halves_change_deg": np.degrees(change).round(2).tolist(),
        "halves_change_norm_deg": round(float(np.degrees(np.linalg.norm(change))), 2),
        "fault_shift_deg": {k: round(v, 2) for k, v in shifts.items()},
    }
