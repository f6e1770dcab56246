"""A robot's geometry as the worker keeps it (the kinematics JSON), made by hand for API and page tests:
every IMU converged, its axis along z unless turned, 0.1 m from it."""

from __future__ import annotations

from typing import Any

import numpy as np

from bodyschema.kinematics import ImuKinematics, JointKinematics, Kinematics
from bodyschema.topology import Topology

__all__ = ["geometry_json"]


def geometry_json(topo: Topology, turned: dict[str, list[float]] | None = None) -> dict[str, Any]:
    """The kinematics JSON of ``topo`` with the IMUs of ``turned`` reporting their given axes."""
    imus = {}
    for name, joint in topo.imu_joint.items():
        axis = np.array((turned or {}).get(name, [0.0, 0.0, 1.0]))
        imus[name] = ImuKinematics(
            name,
            joint,
            axis=axis,
            lever_arm=np.array([0.1, 0.0, 0.0]),
            axis_std_deg=0.05,
            lever_arm_std_m=0.002,
            gain=1.0,
            converged=True,
            gyro_axis=axis,
            gyro_axis_std_deg=0.01,
            axis_converged=True,
        )
    joints = {}
    for j, parent in topo.joint_parent.items():
        mine = tuple(i for i, jj in topo.imu_joint.items() if jj == j)
        joints[j] = JointKinematics(j, parent, mine, mine[0] if mine else None, q_range=(-1.0, 1.0))
    return Kinematics(imus, joints, (), 10.0, 0.0, 600, topo).to_json()
