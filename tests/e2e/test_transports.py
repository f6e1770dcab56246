"""Simulator -> device emulator (own process) -> pty -> CAN/serial ingestor -> store -> worker, in
process and through the ``bodyhealth serve`` daemon.

The tree the worker learns from what came over the wire must equal the tree learned from the same
recording loaded directly: the transports may quantize (1e-6 rad, 0.005 m/s², 0.001 rad/s) but must not
lose, reorder or re-time anything.

The wires (and the store) carry joint positions only, so the worker's estimate runs on velocities
derived from ``q``; the fast estimator needs about a minute of UR5e motion for that to be right (at
20-30 s it is right with the simulator's exact ``qd`` but not with derived ones), hence 60 s here.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from bodyschema.estimate import estimate_topology
from service.ingest.pipeline import Pipeline
from service.ingest.spec import open_source
from service.settings import Settings
from service.store import open_store
from service.worker import Worker
from simulators import simulate
from simulators.recording_io import load_recording, save_recording
from tests.e2e.processes import emulator_command, start_service
from tests.service.multirate_wire import assert_whole_streams_but_the_unpaired_end

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


@pytest.fixture(scope="module")
def recording_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "ur5e.npz"
    save_recording(simulate("ur5e", 60.0, 0, imu_model="mpu6050", excitation="observable", rate=100.0), path)
    return path


@pytest.mark.parametrize("kind", ["can", "serial"])
def test_learned_tree_over_the_wire_equals_direct(
    kind: str, recording_path: Path, tmp_path: Path, e2e_db_url: str
) -> None:
    rec = load_recording(recording_path)
    proc = subprocess.Popen(
        emulator_command(kind, recording_path, "ur5e", tmp_path / "ur5e.json"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    settings = Settings(
        database_url=e2e_db_url,
        window_seconds=rec.duration + 1.0,
        retention_seconds=3600.0,
    )
    store = open_store(settings=settings)
    source = None
    try:
        assert proc.stdout is not None
        fields = dict(kv.split("=", 1) for kv in proc.stdout.readline().split())
        source = open_source(fields["source"], settings)
        with Pipeline(store, [source], settings=settings):
            t0 = time.monotonic()
            while time.monotonic() - t0 < 180:
                info = store.robot("ur5e")
                if info is not None and store.sample_count("ur5e") >= rec.n_samples:
                    break
                time.sleep(0.2)
        counters = source.counters.as_dict()
        assert store.sample_count("ur5e") == rec.n_samples, f"counters: {counters}"
        for bad in ("crc_errors", "sequence_gaps", "decode_errors", "frames_missing", "samples_dropped"):
            assert counters.get(bad, 0) == 0, counters

        stored = store.read_window("ur5e", settings.window_seconds)
        assert stored is not None
        np.testing.assert_allclose(stored.t, rec.t, atol=1e-9)  # device counter × period
        np.testing.assert_allclose(stored.q, rec.q, atol=1e-6)
        np.testing.assert_allclose(stored.gyro, rec.gyro, atol=0.001)

        result = Worker(store, settings).run_cycle()["ur5e"]
        assert result.topology is not None, result.skipped
        direct = estimate_topology(rec)
        assert result.topology.joint_parent == direct.joint_parent
        assert result.topology.imu_joint == direct.imu_joint
        assert direct.joint_parent == rec.truth_parent_map  # and both are right
    finally:
        if source is not None:
            source.close()
        store.close()
        proc.terminate()
        proc.wait(10)


def test_serve_ingests_from_both_transports(recording_path: Path, tmp_path: Path, e2e_db_url: str) -> None:
    """``bodyhealth serve --source can:slcan:PTY --source serial:PTY``: the daemon learns both robots."""
    import os

    import httpx

    rec = load_recording(recording_path)
    direct = estimate_topology(rec).to_json()
    emulators, specs = [], []
    for kind in ("can", "serial"):
        p = subprocess.Popen(
            emulator_command(kind, recording_path, f"arm-{kind}", tmp_path / f"{kind}.json"),
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        emulators.append(p)
        assert p.stdout is not None
        specs.append(dict(kv.split("=", 1) for kv in p.stdout.readline().split())["source"])
    env = {
        **os.environ,
        "BODYHEALTH_WORKER_INTERVAL_SECONDS": "2",
        "BODYHEALTH_WINDOW_SECONDS": str(rec.duration + 1.0),
    }
    sources = [arg for spec in specs for arg in ("--source", spec)]
    serve, url = start_service(e2e_db_url, "--text-logs", *sources, err=tmp_path / "serve.err", env=env)
    try:
        client = httpx.Client(base_url=url, timeout=10)
        learned: dict[str, dict] = {}
        t0 = time.monotonic()
        while len(learned) < 2 and time.monotonic() - t0 < 120 and serve.poll() is None:
            time.sleep(1.0)
            for kind in ("can", "serial"):
                try:
                    r = client.get(f"/api/v1/robots/arm-{kind}/topology")
                except httpx.HTTPError:
                    continue
                meta = r.json().get("current_meta") if r.status_code == 200 else None
                # wait for a cycle that saw the whole recording
                if meta and meta["window_end_t"] is not None and meta["window_end_t"] >= rec.t[-1] - 1e-6:
                    learned[kind] = r.json()["current"]
        assert len(learned) == 2, (tmp_path / "serve.err").read_text()[-3000:]
        for kind, topo in learned.items():
            assert topo["joints"] == direct["joints"], kind
            assert topo["imus"] == direct["imus"], kind
    finally:
        serve.terminate()
        assert serve.wait(30) == 0
        for p in emulators:
            p.terminate()
            p.wait(10)


@pytest.mark.parametrize("kind", ["can", "serial"])
def test_multirate_robot_over_the_wire(kind: str, tmp_path: Path, e2e_db_url: str) -> None:
    """A multi-rate recording (``sensing="robot"``: encoders at 250 Hz, IMUs at 100 Hz, own clocks) saved
    to .npz, played by the emulator process as two stamped streams, ingested into the store: both
    streams come back on their own stamps, to the wire's resolution (1 µs stamps, half an LSB of
    value), and the preset's dropped samples are counted as lost on the wire, not invented."""
    rec = simulate("ur5e", 10.0, 0, sensing="robot")
    assert rec.is_multirate and rec.t_q is not None and rec.q is not None
    path = tmp_path / "robot.npz"
    save_recording(rec, path)
    proc = subprocess.Popen(
        emulator_command(kind, path, "ur5e", tmp_path / "ur5e.json"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    settings = Settings(database_url=e2e_db_url, window_seconds=rec.duration + 2.0, retention_seconds=3600.0)
    store = open_store(settings=settings)
    source = None
    try:
        assert proc.stdout is not None
        fields = dict(kv.split("=", 1) for kv in proc.stdout.readline().split())
        offset = float(fields["time_offset_s"])
        source = open_source(fields["source"], settings)
        with Pipeline(store, [source], settings=settings):
            t0 = time.monotonic()
            while time.monotonic() - t0 < 120:
                if store.robot("ur5e") is not None and store.sample_count("ur5e") >= rec.n_samples:
                    break
                time.sleep(0.2)
            time.sleep(0.5)  # the last encoder samples ride with the last IMU batch
        counters = source.counters.as_dict()
        stored = store.read_window("ur5e", settings.window_seconds)
        assert stored is not None and stored.t_q is not None and stored.q is not None
        assert store.sample_count("ur5e") == stored.n_samples, f"counters: {counters}"
        n, m = assert_whole_streams_but_the_unpaired_end(stored.t - offset, stored.t_q - offset, rec)
        n, m = rec.n_samples - n, len(rec.t_q) - m  # what arrived
        np.testing.assert_allclose(stored.t - offset, rec.t[:n], rtol=0, atol=0.5e-6 + 1e-9)
        np.testing.assert_allclose(stored.t_q - offset, rec.t_q[:m], rtol=0, atol=0.5e-6 + 1e-9)
        np.testing.assert_allclose(stored.q, rec.q[:m], rtol=0, atol=0.5e-6 + 1e-9)
        np.testing.assert_allclose(stored.acc, rec.acc[:n], rtol=0, atol=0.0025 + 1e-9)
        np.testing.assert_allclose(stored.gyro, rec.gyro[:n], rtol=0, atol=0.0005 + 1e-9)
        lost = counters.get("sequence_gaps" if kind == "serial" else "samples_missing", 0)
        assert lost > 0, counters  # the robot preset drops 0.5 % of each stream's samples
        for bad in ("crc_errors", "decode_errors", "frames_missing", "samples_dropped", "clock_jumps"):
            assert counters.get(bad, 0) == 0, counters
    finally:
        if source is not None:
            source.close()
        store.close()
        proc.terminate()
        proc.wait(10)
