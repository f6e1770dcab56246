"""Durability: SIGKILL an ingest process mid-write, repeatedly; every frame it reported committed is
intact, the SQLite file passes its integrity check, and a restart resumes without gaps or duplicates."""

from __future__ import annotations

import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bodyschema.recording import Recording
from service.store import Store, open_store
from simulators.recording_io import save_recording
from tests.waits import cpu_bound

REPO = Path(__file__).resolve().parents[2]


def _committed(log: Path) -> tuple[float, int]:
    """(device time of the last reported commit, number of reports) from the commit log."""
    lines = [json.loads(ln) for ln in log.read_text().splitlines() if ln.strip()] if log.exists() else []
    return (max((ln["t_end"] for ln in lines), default=-math.inf), len(lines))


def _start(db_url: str, rec: Path, log: Path) -> subprocess.Popen[bytes]:
    # Many small transactions (the writer commits what is queued, no linger), so kills land inside them.
    env = {**os.environ, "PYTHONPATH": str(REPO), "BODYHEALTH_INGEST_COMMIT_INTERVAL_SECONDS": "0"}
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "service.ingest.pipeline",
            "--database-url",
            db_url,
            "--commit-log",
            str(log),
            f"replay:{rec}@25?chunk=0.05&robot=arm",
        ],
        cwd=REPO,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )


@pytest.mark.slow
def test_sigkill_mid_ingest_loses_no_committed_frame(
    db_url: str, tmp_path: Path, rng: np.random.Generator
) -> None:
    """On SQLite (WAL) and on PostgreSQL: every reported commit survives each kill -9, exactly once."""
    n, k = 4000, 12  # 40 s at 100 Hz, 12 IMUs: about 1.6 s of ingest per full run at 25x
    ref = Recording(
        t=np.arange(n) / 100.0,
        joint_names=["j1", "j2", "j3"],
        q=rng.normal(size=(n, 3)),
        imu_names=[f"imu{i}" for i in range(k)],
        acc=rng.normal(size=(n, k, 3)),
        gyro=rng.normal(size=(n, k, 3)),
    )
    rec_path, log = tmp_path / "arm.npz", tmp_path / "commits.jsonl"
    save_recording(ref, rec_path)
    open_store(db_url).close()  # the schema step (`bodyhealth db upgrade`) comes before any ingest

    kills = 0
    for _attempt in range(12):
        if kills == 5:
            break
        before, reports_before = _committed(log)
        proc = _start(db_url, rec_path, log)
        # Kill after a random number of further commits (the process reports each one).
        want = reports_before + int(rng.integers(1, 8))
        deadline = time.monotonic() + cpu_bound(60)  # commits of a process that must start first
        while _committed(log)[1] < want and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(float(rng.uniform(0.0, 0.05)))  # land anywhere in the next transaction
        if proc.poll() is not None:  # it finished before we struck
            assert proc.returncode == 0, proc.stderr.read().decode() if proc.stderr else ""
            break
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
        kills += 1
        t_committed, _ = _committed(log)
        assert t_committed > before  # it made progress after resuming
        if db_url.startswith("sqlite:///"):
            with sqlite3.connect(db_url.removeprefix("sqlite:///")) as conn:
                assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        with Store(db_url) as store:
            got = store.read_between("arm", -math.inf, math.inf)
            m = ref.t <= t_committed
            # Every reported frame is there, bit-exact, and nothing is there twice.
            np.testing.assert_array_equal(got.t[: m.sum()], ref.t[m])
            np.testing.assert_array_equal(got.acc[: m.sum()], ref.acc[m])
            np.testing.assert_array_equal(got.q[: m.sum()], ref.q[m])
            assert store.sample_count("arm") == got.n_samples
    print(f"killed {kills} times at commits up to t={_committed(log)[0]:.2f} s")
    assert kills >= 3, "the ingest finished too fast to be killed mid-write"

    # The final restart resumes and completes: the whole recording, once.
    proc = _start(db_url, rec_path, log)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err.decode()
    with Store(db_url) as store:
        got = store.read_between("arm", -math.inf, math.inf)
        assert store.sample_count("arm") == n == got.n_samples
        for key in ("t", "q", "acc", "gyro"):
            np.testing.assert_array_equal(getattr(got, key), getattr(ref, key))
