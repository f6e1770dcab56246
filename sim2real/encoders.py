"""Encoder effects of a recorded robot, against its model (a catalog name or an MJCF/URDF file).

The glue between a recording, a robot model file or catalog name, and
:func:`bodyschema.discrepancy.encoders.analyze_encoders`: the model's product-of-exponentials form
(:func:`simulators.robot_chain.robot_chain`); joints and IMUs are matched by name.

Example
-------
>>> from simulators.simulation import simulate
>>> rec = simulate("ur5e", 30.0, seed=0, sensing="robot")
>>> rep = encoder_analysis(rec, "ur5e")
>>> rep.names
['encoder_time_offset']
"""

from __future__ import annotations

import os

from bodyschema.discrepancy.encoders import EncoderOptions, EncoderReport, analyze_encoders
from bodyschema.recording import Recording

__all__ = ["encoder_analysis"]


def encoder_analysis(rec: Recording, robot: str, options: EncoderOptions | None = None) -> EncoderReport:
    """The encoder effects the IMUs of ``rec`` reveal against ``robot``'s model
    (:func:`~bodyschema.discrepancy.encoders.analyze_encoders`; its rules for joints and IMUs)."""
    from simulators.robot import Robot
    from simulators.robot_chain import robot_chain

    bot = Robot.from_file(robot) if os.path.exists(robot) else Robot.from_catalog(robot)
    report = analyze_encoders(robot_chain(bot), rec, options)
    report.meta["robot"] = robot
    return report
