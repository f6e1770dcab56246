"""The whole service as a process: ``bodyhealth serve --demo`` at 20× real time on a temporary SQLite
file, its dashboard in a headless Chromium, four damage kinds injected in turn (tests/e2e/demo.py says
what is checked; the PostgreSQL run, tests/e2e/test_serve_postgres.py, injects the other two); and a
replaying service drains its ingest and exits 0 on SIGINT and SIGTERM.
"""

from __future__ import annotations

import signal
import time
from functools import partial
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.e2e.browser import NEEDS_CHROMIUM
from tests.e2e.demo import DAMAGES, PG_KINDS, check_dashboard, check_demo, demo_service
from tests.e2e.processes import start_service
from tests.waits import cpu_bound

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


@NEEDS_CHROMIUM
@pytest.mark.parametrize("e2e_db_url", ["sqlite"], indirect=True)
def test_demo_learns_baselines_and_alerts_on_each_damage(
    e2e_db_url: str, tmp_path: Path, browser: Any
) -> None:
    """The demo as ``make run`` serves it (SQLite), with the dashboard on it: once the baselines are
    learned, the page draws them and a damage injected from the page becomes an alert row; then the
    damages over the API."""
    with demo_service(e2e_db_url, tmp_path) as service:
        page = partial(check_dashboard, service, browser, shot=tmp_path / "dashboard.png")
        check_demo(service, [d for d in DAMAGES if d[0] not in PG_KINDS], page=page)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_drains_and_exits_zero(tmp_path: Path, e2e_db_url: str, sig: signal.Signals) -> None:
    import json

    import numpy as np

    from simulators.recording_io import save_recording
    from tests.builders import synth

    rec_path = tmp_path / "run.npz"
    save_recording(synth(np.random.default_rng(0), seconds=60.0), rec_path)
    log = tmp_path / "commits.jsonl"
    proc, url = start_service(
        e2e_db_url,
        "--source",
        f"replay:{rec_path}@5?robot=arm",
        "--commit-log",
        str(log),
        err=tmp_path / "err.txt",
        cwd=tmp_path,
    )
    try:
        deadline = time.monotonic() + cpu_bound(60.0)
        while time.monotonic() < deadline and not (log.exists() and log.read_text().count("\n") >= 5):
            assert proc.poll() is None, (tmp_path / "err.txt").read_text()[-3000:]
            time.sleep(0.1)
        r = httpx.get(f"{url}/livez", timeout=10)
        assert r.json() == {"status": "ok"}
        proc.send_signal(sig)
        assert proc.wait(cpu_bound(60.0)) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)
    lines = [json.loads(x) for x in (tmp_path / "err.txt").read_text().splitlines() if x.startswith("{")]
    drained = [x for x in lines if x["msg"] == "ingest drained"]
    assert drained and drained[0]["counters"]["stored"] == drained[0]["counters"]["received"]
    assert drained[0]["counters"]["queue_depth"] == 0
    assert any(x["msg"] == "service stopped" for x in lines)
    committed = json.loads(log.read_text().splitlines()[-1])["samples"]
    assert committed == drained[0]["counters"]["stored"]
