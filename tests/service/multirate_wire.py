"""What a multi-rate recording played over a device wire must deliver, shared by the serial and CAN
round-trip tests."""

from __future__ import annotations

import numpy as np

from bodyschema.recording import Recording
from emulators.devices import STAMP_TICK_S

__all__ = ["assert_whole_streams_but_the_unpaired_end"]


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
