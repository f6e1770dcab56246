"""Simulator -> device emulator (own process) -> pty -> CAN/serial ingestor -> store -> worker.

The tree the worker learns from what came over the wire must equal the tree learned from the same
recording loaded directly: the transports may quantize (1e-6 rad, 0.005 m/s², 0.001 rad/s) but must not
lose, reorder or re-time anything.

The wires (and the store) carry joint positions only, so the worker's estimate runs on velocities
derived from ``q``; the fast estimator needs about a minute of UR5e motion for that to be right (at
20-30 s it is right with the simulator's exact ``qd`` but not with derived ones), hence 60 s here.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bodyschema.estimate import estimate_topology
from service.ingest.pipeline import Pipeline
from service.ingest.spec import open_source
from service.settings import Settings
from service.store import Store
from service.worker import Worker
from simulators import simulate
from simulators.recording_io import load_recording, save_recording

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


@pytest.fixture(scope="module")
def recording_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "ur5e.npz"
    save_recording(simulate("ur5e", 60.0, 0, imu_model="mpu6050", excitation="observable", rate=100.0), path)
    return path


@pytest.mark.parametrize("kind", ["can", "serial"])
def test_learned_tree_over_the_wire_equals_direct(kind: str, recording_path: Path, tmp_path: Path) -> None:
    rec = load_recording(recording_path)
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.emulators", kind, "--recording", str(recording_path),
         "--robot", "ur5e", "--speed", "0", "--linger", "120", "--config-out", str(tmp_path / "ur5e.json")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    settings = Settings(database_url=f"sqlite:///{tmp_path / 'e2e.db'}", window_seconds=rec.duration + 1.0,
                        retention_seconds=3600.0)
    store = Store(settings=settings)
    source = None
    try:
        assert proc.stdout is not None
        fields = dict(kv.split("=", 1) for kv in proc.stdout.readline().split())
        source = open_source(fields["source"], settings)
        with Pipeline(store, [source], settings=settings):
            t0 = time.monotonic()
            while time.monotonic() - t0 < 90:
                info = store.robot("ur5e")
                if info is not None and store.sample_count("ur5e") >= rec.n_samples:
                    break
                time.sleep(0.2)
        counters = source.counters.as_dict()
        assert store.sample_count("ur5e") == rec.n_samples, counters
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
