"""Device emulators: a recording or a simulated robot played onto a pty as a real device would send it.

- :class:`~emulators.devices.SlcanEmulator`: an slcan USB-CAN adapter on a bus carrying the
  project CAN layout (classic or CAN FD);
- :class:`~emulators.devices.SerialEmulator`: a device streaming serial frames;
- :class:`~emulators.pty_port.PtyPort`: the pty underneath, with a stable link and unplug/replug.

:func:`emulators.rosbag.write_rosbag` writes a recording as a ROS bag (ROS 2 MCAP or sqlite3, ROS 1), as
a robot's ROS drivers would have logged it (in its own module, so the device emulators never load
``rosbags``).

The devices play a multi-rate recording (encoders on their own stamps) as a multi-rate device: two stamped
streams (docs/wire-formats.md).

Command line: ``python -m emulators can|serial --robot ur5e --seconds 30 --seed 0``
(``--sensing robot``: a realistic multi-rate robot).
"""

from emulators.devices import SerialEmulator, SlcanEmulator
from emulators.pty_port import PtyPort

__all__ = ["PtyPort", "SerialEmulator", "SlcanEmulator"]
