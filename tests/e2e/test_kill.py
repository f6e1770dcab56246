"""SIGKILL the daemon mid-ingest, restart it, repeat: no committed frame lost, nothing corrupted, and
the replay resumes where the store left off until the stored data equals the recording exactly.

The suite kills 3 times per backend; ``BODYHEALTH_KILLS=50`` runs the long check (50 kills per
backend, about 3 minutes each) before a release or after a change to the writer."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from service.store import open_store
from simulators.recording_io import save_recording
from tests.builders import synth
from tests.e2e.processes import serve_command

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

ROBOT = "arm"
#: SIGKILLs per run (module doc).
KILLS = int(os.environ.get("BODYHEALTH_KILLS", "3"))


def start(tmp: Path, db: str, rec_path: Path, log: Path, speed: float) -> subprocess.Popen:
    env = {**os.environ, "BODYHEALTH_WORKER_INTERVAL_SECONDS": "1", "BODYHEALTH_WINDOW_SECONDS": "5"}
    cmd = serve_command(
        0, db, "--source", f"replay:{rec_path}@{speed:g}?robot={ROBOT}", "--commit-log", str(log)
    )
    return subprocess.Popen(
        cmd, cwd=tmp, env=env, stdout=subprocess.DEVNULL, stderr=open(tmp / f"{log.stem}.err", "w")
    )


def committed(log: Path) -> int:
    """Samples this run reported committed (the commit log's running total)."""
    if not log.exists():
        return 0
    lines = [ln for ln in log.read_text().splitlines() if ln.strip()]
    return json.loads(lines[-1])["samples"] if lines else 0


def check_db(db_url: str, rec_t: np.ndarray, rec_gyro: np.ndarray) -> int:
    if db_url.startswith("sqlite:///"):
        with sqlite3.connect(db_url.removeprefix("sqlite:///")) as conn:
            assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    with open_store(db_url) as store:
        n = store.sample_count(ROBOT) if store.robot(ROBOT) else 0
        if n:
            got = store.read_between(ROBOT, -np.inf, np.inf)
            assert got is not None and got.n_samples == n  # no duplicates hidden by the merge
            # what is stored is exactly the start of the recording: no gap, no duplicate, no garbage
            np.testing.assert_array_equal(got.t, rec_t[:n])
            np.testing.assert_array_equal(got.gyro, rec_gyro[:n])
    return n


def test_sigkill_mid_ingest_loses_nothing_committed(
    e2e_db_url: str, tmp_path: Path, rng: np.random.Generator
) -> None:
    rec = synth(rng, seconds=150.0 * max(1.0, KILLS / 3))  # each run stores 0.3-1.5 k samples, 100 Hz
    rec_path = tmp_path / "run.npz"
    save_recording(rec, rec_path)
    db_url = e2e_db_url
    stored_before = 0
    for attempt in range(KILLS):
        log = tmp_path / f"commits{attempt}.jsonl"
        proc = start(tmp_path, db_url, rec_path, log, speed=15)
        try:
            deadline = time.monotonic() + 60
            target = int(rng.integers(300, 1500))
            while committed(log) < target and time.monotonic() < deadline and proc.poll() is None:
                time.sleep(0.05)
            assert proc.poll() is None, (tmp_path / f"{log.stem}.err").read_text()[-3000:]
            assert committed(log) >= target
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait(20)
        n = check_db(db_url, rec.t, rec.gyro)
        # every commit the killed process reported is there, on top of what earlier runs stored
        assert n >= stored_before + committed(log), (attempt, n, stored_before, committed(log))
        assert n < rec.n_samples, "the kill came after the whole recording was in: test too slow"
        stored_before = n
    # a last, clean run finishes the recording and exits 0 on SIGTERM
    log = tmp_path / "commits_final.jsonl"
    proc = start(tmp_path, db_url, rec_path, log, speed=200)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if stored_before + committed(log) >= rec.n_samples:
                break
            time.sleep(0.1)
        assert stored_before + committed(log) == rec.n_samples
    finally:
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(60)
    assert rc == 0, (tmp_path / "commits_final.err").read_text()[-3000:]
    assert check_db(db_url, rec.t, rec.gyro) == rec.n_samples
    err = (tmp_path / "commits_final.err").read_text()
    assert '"msg": "ingest drained"' in err and '"msg": "service stopped"' in err
