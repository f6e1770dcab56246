"""``bodyhealth serve`` as a process, a robot restarting under it: frames pushed over HTTP with the
device clock going back are kept through the ingest writer's prunes, the robot reports a new epoch, and
the worker learns from the new run's window. On SQLite and PostgreSQL.

Before epochs, the restarted run's frames were pruned within one prune interval (they ended more than
the retention before the old run's newest frame) and every later topology came from the old window.
"""

from __future__ import annotations

import os
import re
import subprocess
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from bodyschema.recording import Recording
from tests.builders import synth
from tests.e2e.processes import start_service, wait_answering

pytestmark = [pytest.mark.e2e]


def post_run(c: httpx.Client, rec: Recording, offset: float, batch: int = 200) -> None:
    for s in range(0, rec.n_samples, batch):
        sl = slice(s, s + batch)
        body = {
            "t": (rec.t[sl] + offset).tolist(),
            "joint_names": list(rec.joint_names),
            "q": rec.q[sl].tolist(),
            "imu_names": list(rec.imu_names),
            "acc": rec.acc[sl].tolist(),
            "gyro": rec.gyro[sl].tolist(),
        }
        resp = c.post("/api/v1/robots/arm/frames", json=body)
        assert resp.status_code == 201, resp.text


def pruned(c: httpx.Client) -> float:
    text = c.get("/metrics").text
    m = re.search(r'^bodyhealth_ingest_events_total\{event="pruned"\} (\S+)$', text, re.M)
    return float(m.group(1)) if m else 0.0


def test_restarted_clock_is_kept_and_learned_from(e2e_db_url: str, tmp_path: Path) -> None:
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("BODYHEALTH_")},
        "BODYHEALTH_RETENTION_SECONDS": "60",
        "BODYHEALTH_WINDOW_SECONDS": "10",
        "BODYHEALTH_WORKER_INTERVAL_SECONDS": "0.5",
        "BODYHEALTH_PRUNE_INTERVAL_SECONDS": "0.2",
    }
    proc, url = start_service(e2e_db_url, err=tmp_path / "serve.err", env=env, cwd=tmp_path)
    rng = np.random.default_rng(12)
    try:
        with httpx.Client(base_url=url, timeout=30) as c:
            wait_answering(proc, c, tmp_path / "serve.err", "/readyz")
            post_run(c, synth(rng, seconds=12), offset=1000.0)  # the old run, 1000.00 .. 1011.99 s
            post_run(c, synth(rng, seconds=12), offset=0.0)  # the robot restarted: 0.00 .. 11.99 s
            robot = c.get("/api/v1/robots/arm").json()
            assert (robot["epoch"], robot["epoch_start_t"]) == (1, 0.0)
            assert robot["last_frame_t"] == pytest.approx(11.99)

            deadline = time.monotonic() + 90
            while True:
                meta = c.get("/api/v1/robots/arm/topology").json()["current_meta"]
                if meta is not None and meta["window_end_t"] == pytest.approx(11.99):
                    break
                assert time.monotonic() < deadline, f"no topology of the new run within 90 s: {meta}"
                time.sleep(0.5)
            time.sleep(1.0)  # five more prune intervals
            assert pruned(c) == 0.0  # the new run is within the retention; the old epoch waits
            assert c.get("/api/v1/robots/arm").json()["epoch"] == 1
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
