"""Device emulators on ptys: slcan adapter behaviour, CAN over slcan with a replug, the command line."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest
import serial

from bodyschema.recording import Recording
from emulators.devices import SlcanEmulator
from service.ingest.can import CanSource, open_bus
from service.ingest.device import DeviceConfig
from service.ingest.serial_frame import ACC_LSB, GYRO_LSB, Q_LSB
from simulators.recording_io import save_recording


def _rec(rng, T, n=6, k=12):
    return Recording(
        t=np.arange(T) * 0.01 + 2.0,
        joint_names=[f"j{i}" for i in range(n)],
        q=rng.uniform(-3, 3, (T, n)),
        imu_names=[f"imu{i}" for i in range(k)],
        acc=rng.normal(0, 10, (T, k, 3)),
        gyro=rng.normal(0, 2, (T, k, 3)),
    )


def test_slcan_adapter_answers_commands_and_streams_only_when_open(rng):
    em = SlcanEmulator(_rec(rng, 5, n=1, k=1))
    em.start()
    port = serial.Serial(em.port.name, timeout=0.3)
    time.sleep(0.2)
    assert port.read(100) == b""  # channel closed: nothing on the line
    port.timeout = 3.0
    port.write(b"S6\rV\rN\rXYZ\r")
    assert port.read(1 + 6 + 6 + 1) == b"\rV1013\rNBH01\r\a"
    port.write(b"O\r")
    lines = port.read(1 + 5 * 3 * 22)  # OK, then 5 samples of a joint, an acc and a gyro frame
    assert lines.startswith(b"\rt0808") and lines.count(b"\r") == 1 + 5 * 3
    assert [x[:5] for x in lines.split(b"\r")[1:4]] == [b"t0808", b"t1008", b"t1808"]
    port.close()
    em.stop()


@pytest.mark.slow
def test_can_over_slcan_pty_with_replug(tmp_path, rng):
    T = 3000
    rec = _rec(rng, T)
    link = str(tmp_path / "slcan0")
    em = SlcanEmulator(rec, robot="arm", link=link)
    cfg = em.device_config()
    src = CanSource(cfg, lambda: open_bus("slcan", link), backoff=(0.01, 0.1), idle_flush_s=0.3)
    em.start()
    got = []

    def until(cond, timeout=20.0):
        t0 = time.monotonic()
        while not cond() and time.monotonic() - t0 < timeout:
            got.extend(src.read(0.1))

    until(lambda: sum(b.n_samples for b in got) >= 300)
    em.unplug()
    until(lambda: src.counters.extra.get("bus_errors", 0) >= 1)
    time.sleep(0.2)
    em.plug()
    until(lambda: bool(got) and got[-1].t[-1] > rec.t[-1] - 0.015)
    src.close()
    em.stop()
    c = src.counters.as_dict()
    assert c["reconnects"] == 1 and c["bus_errors"] >= 1
    assert c.get("decode_errors", 0) == 0 and c.get("unknown_ids", 0) == 0
    full = [b for b in got if len(b.imu_names) == 12]
    t = np.concatenate([b.t for b in full])
    idx = np.rint((t - 2.0) / 0.01).astype(int)
    assert np.all(np.diff(np.concatenate([b.t for b in got])) > 0)
    assert idx[0] == 0 and idx[-1] == T - 1 and len(idx) >= T - 300
    np.testing.assert_allclose(np.concatenate([b.q for b in full]), rec.q[idx], atol=Q_LSB)
    np.testing.assert_allclose(np.concatenate([b.acc for b in full]), rec.acc[idx], atol=ACC_LSB)
    np.testing.assert_allclose(np.concatenate([b.gyro for b in full]), rec.gyro[idx], atol=GYRO_LSB)


def test_command_line_prints_a_usable_source_spec(tmp_path, rng):
    rec = _rec(rng, 200, n=2, k=3)
    save_recording(rec, tmp_path / "r.npz")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "emulators",
            "serial",
            "--recording",
            str(tmp_path / "r.npz"),
            "--robot",
            "bench-arm",
            "--speed",
            "0",
            "--linger",
            "5",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        fields = dict(kv.split("=", 1) for kv in line.split())
        assert fields["source"].startswith("serial:") and "config=" in fields["source"]
        assert DeviceConfig.load(fields["config"]).robot == "bench-arm"
        from service.ingest.serial import open_from_spec

        src = open_from_spec(fields["source"].partition(":")[2])
        got = []
        t0 = time.monotonic()
        while sum(b.n_samples for b in got) < 200 and time.monotonic() - t0 < 15:
            got += src.read(0.2)
        src.close()
        t = np.concatenate([b.t for b in got])
        np.testing.assert_allclose(t, rec.t, atol=1e-9)
    finally:
        proc.terminate()
        proc.wait(10)


def test_can_fd_over_slcan_pty(rng):
    T = 400
    rec = _rec(rng, T, n=20, k=7)
    em = SlcanEmulator(rec, fd=True, robot="fd-arm")
    cfg = em.device_config()
    assert cfg.extra["can"]["layout"] == "fd"
    src = CanSource(cfg, lambda: open_bus("slcan", em.port.name), idle_flush_s=0.3)
    em.start()
    got = []
    t0 = time.monotonic()
    while sum(b.n_samples for b in got) < T and time.monotonic() - t0 < 20:
        got += src.read(0.2)
    src.close()
    em.stop()
    assert src.counters.extra["frames"] == T * (2 + 7)  # 2 joint frames of 64 B, 7 IMU frames of 16 B
    t = np.concatenate([b.t for b in got])
    np.testing.assert_allclose(t, rec.t, atol=1e-9)
    np.testing.assert_allclose(np.concatenate([b.q for b in got]), rec.q, atol=Q_LSB)
    np.testing.assert_allclose(np.concatenate([b.acc for b in got]), rec.acc, atol=ACC_LSB)
