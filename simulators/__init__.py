"""Physics: MuJoCo robots with IMUs, the IMU error model, excitation, damage scenarios, the robot farm.

The entry points most callers need are re-exported lazily (importing :mod:`simulators.recording_io`
alone does not load MuJoCo):

>>> from simulators import simulate
>>> rec = simulate("ur5e", seconds=0.5, seed=0)
>>> rec.n_joints, rec.n_imus
(6, 12)
"""

from __future__ import annotations

from typing import Any

__all__ = ["CATALOG", "Farm", "Robot", "Simulation", "simulate"]

_LAZY = {
    "simulate": "simulators.simulation",
    "Simulation": "simulators.simulation",
    "Farm": "simulators.farm",
    "Robot": "simulators.robot",
    "CATALOG": "simulators.catalog",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'simulators' has no attribute {name!r}")
