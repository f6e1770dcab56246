"""``python -m emulators can|serial``: play a robot onto a pty as an slcan adapter or serial device.

Prints one line ``pty=PATH config=PATH source=SPEC`` (SPEC is what ``bodyhealth serve --source`` takes),
then streams until the recording ends and ``--linger`` seconds pass, or until interrupted.

A multi-rate recording (``--sensing robot``, or a multi-rate ``--recording``) is sent as a multi-rate
device sends it: encoder and IMU samples as two streams with their own stamps (docs/wire-formats.md);
``--streams`` sends a single-clock recording that way too. The line then adds ``time_offset_s=X``, the
seconds the device's stamps run ahead of the recording's times (non-zero only for a recording that
starts before 0).

Examples::

    python -m emulators can --robot ur5e --seconds 30 --seed 0
    python -m emulators serial --recording rec.npz --speed 1 --link /tmp/robot-tty
    python -m emulators serial --robot ur5e --seconds 10 --sensing robot
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import threading
from pathlib import Path

from bodyschema.recording import Recording
from emulators.devices import SerialEmulator, SlcanEmulator


def _recording(args: argparse.Namespace) -> Recording:
    if args.recording:
        from simulators.recording_io import load_recording

        return load_recording(args.recording)
    from simulators import simulate  # type: ignore[attr-defined]

    return simulate(
        args.robot,
        args.seconds,
        args.seed,
        imu_model=args.imu_model,
        excitation=args.excitation,
        rate=args.rate,
        sensing=args.sensing,
    )


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m emulators", description=__doc__.splitlines()[0])
    p.add_argument("kind", choices=("can", "serial"), help="slcan CAN adapter or serial frames")
    p.add_argument("--robot", default="ur5e", help="robot to simulate, and the robot name sent to the host")
    p.add_argument("--recording", help="play this .npz recording instead of simulating")
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rate", type=float, default=100.0, help="sample rate when simulating, Hz")
    p.add_argument("--imu-model", default="mpu6050")
    p.add_argument("--excitation", default="observable")
    p.add_argument("--speed", type=float, default=1.0, help="1 = real time, 0 = as fast as the reader takes")
    p.add_argument("--link", help="keep a symlink to the current pty here (stable across replugs)")
    p.add_argument("--config-out", help="where to write the device config JSON (default: a temp file)")
    p.add_argument("--can-fd", action="store_true", help="CAN: send the CAN FD variant of the layout")
    p.add_argument(
        "--sensing",
        default="ideal",
        help="when simulating: sensing preset (ideal, robot) or options as JSON; anything but ideal makes a "
        "multi-rate recording, sent as two streams",
    )
    p.add_argument(
        "--streams",
        action="store_true",
        help="send encoder and IMU samples as two stamped streams (a multi-rate recording always is)",
    )
    p.add_argument("--linger", type=float, default=5.0, help="seconds to keep the pty open after the end")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    rec = _recording(args)
    streams = True if args.streams else None  # None: as the recording is
    if args.kind == "can":
        em: SlcanEmulator | SerialEmulator = SlcanEmulator(
            rec, fd=args.can_fd, robot=args.robot, speed=args.speed, link=args.link, streams=streams
        )
    else:
        em = SerialEmulator(rec, robot=args.robot, speed=args.speed, link=args.link, streams=streams)
    cfg_path = Path(
        args.config_out or os.path.join(tempfile.mkdtemp(prefix="bodyhealth-emu-"), f"{args.robot}.json")
    )
    em.device_config().save(cfg_path)
    spec = (
        f"can:slcan:{em.port.name}" if args.kind == "can" else f"serial:{em.port.name}"
    ) + f"?config={cfg_path}"
    extra = f" time_offset_s={em.time_offset_s}" if em.streams else ""
    print(f"pty={em.port.name} config={cfg_path} source={spec}{extra}", flush=True)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    em.start()
    while not stop.is_set() and not em.wait_done(0.2):
        pass
    if not stop.is_set():
        print(f"sent {em.sent} samples", file=sys.stderr, flush=True)
        stop.wait(args.linger)
    em.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
