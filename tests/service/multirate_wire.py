"""What a multi-rate recording played over a device wire must deliver, shared by the serial and CAN
round-trip tests."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from bodyschema.recording import Recording
from emulators.devices import STAMP_TICK_S
from service.frames import FrameBatch

__all__ = ["assert_whole_streams_but_the_unpaired_end", "read_until_drained"]

#: Seconds with nothing read, after the device is done, that end the reading: a read step (0.2 s), the
#: CAN source's idle flush (0.3 s) and as much again for a loaded machine.
QUIET_S = 1.0


def read_until_drained(
    read: Callable[[float], list[FrameBatch]],
    device_done: Callable[[], bool],
    complete: Callable[[list[FrameBatch]], bool],
    limit_s: float = 40.0,
) -> list[FrameBatch]:
    """The batches ``read(0.2)`` gives until ``complete(got)``, or until the device is done and nothing
    came for :data:`QUIET_S`: the samples still in the host's joiner then wait for samples of the
    other stream that will never come (:func:`assert_whole_streams_but_the_unpaired_end`), and
    waiting for them only ran into ``limit_s`` (seen: 40 s, in a test of 0.2 s otherwise). ``limit_s``
    is a ceiling for a device that never ends."""
    got: list[FrameBatch] = []
    t0 = last = time.monotonic()
    done_at: float | None = None
    while time.monotonic() - t0 < limit_s:
        new = read(0.2)
        now = time.monotonic()
        if new:
            got += new
            last = now
        if complete(got):
            break
        if done_at is None and device_done():
            done_at = now
        if done_at is not None and now - max(last, done_at) > QUIET_S:
            break
    return got


def assert_whole_streams_but_the_unpaired_end(
    t: np.ndarray, t_q: np.ndarray, rec: Recording
) -> tuple[int, int]:
    """Both streams arrive as exact prefixes of the recording's, short only of samples stamped after
    the other stream's last delivered sample: a multi-rate batch needs a sample of each stream, so when
    the device stops, samples past the other stream's end may still wait in the host's joiner (how many
    depends on when the host last read). Returns how many of each were still waiting."""
    assert rec.t_q is not None
    missing_imu, missing_enc = rec.n_samples - len(t), len(rec.t_q) - len(t_q)
    assert missing_imu >= 0 and missing_enc >= 0, (missing_imu, missing_enc)
    assert np.all(rec.t[len(t) :] > t_q[-1] - STAMP_TICK_S), "an IMU sample inside the encoder span was lost"
    assert np.all(rec.t_q[len(t_q) :] > t[-1] - STAMP_TICK_S), (
        "an encoder sample inside the IMU span was lost"
    )
    assert missing_imu <= 2 and missing_enc <= 3, (missing_imu, missing_enc)  # a period of the other stream
    return missing_imu, missing_enc
