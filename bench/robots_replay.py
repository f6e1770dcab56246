"""The service on the untouched robot logs: ``bodyhealth serve --source replay:REC.npz@SPEED?loop=1``
until the replay has covered ``minutes`` of log time, then every alert the robot raised (any state).

An untouched log must raise none. The service runs as its own process on a temporary SQLite file with
its default settings; the robot's status (the baseline learned and its kind: a topology, or a
floating-base robot's floating baseline; newest device time; what the worker says it waits on) is read
through the REST API like any client does.
"""

from __future__ import annotations

import json
import re
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["replay_alerts"]


def _start(db: Path, spec: str, err: Path, cwd: Path) -> tuple[subprocess.Popen[str], str]:
    """``bodyhealth serve`` on a port the system picks; its base URL once bound."""
    cmd = [sys.executable, "-m", "cli", "serve", "--port", "0", "--database-url", f"sqlite:///{db}"]
    with err.open("w") as err_file:
        proc = subprocess.Popen(
            [*cmd, "--source", spec], cwd=cwd, stdout=subprocess.PIPE, stderr=err_file, text=True
        )
    assert proc.stdout is not None
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if select.select([proc.stdout], [], [], 0.5)[0]:
            m = re.search(r"(http://\S+?:\d+)/", proc.stdout.readline())
            if m:
                return proc, m.group(1)
        if proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError(f"service did not start:\n{err.read_text()[-2000:]}")


def _errors(err: Path) -> dict[str, int]:
    """The service's logged errors, by their last line."""
    out: dict[str, int] = {}
    for line in err.read_text().splitlines():
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if rec.get("level") in ("error", "critical"):
            exc = str(rec.get("exc") or rec.get("msg", "")).strip().splitlines()
            key = exc[-1][:160] if exc else "?"
            out[key] = out.get(key, 0) + 1
    return out


def replay_alerts(rec_path: Path, robot: str, minutes: float, speed: float, t_start: float) -> dict[str, Any]:
    """Replay ``rec_path`` looped at ``speed`` for ``minutes`` of log time (device time from the
    recording's first stamp ``t_start``); the alerts and status."""
    import httpx

    with tempfile.TemporaryDirectory(prefix="bench-replay-") as tmp:
        d = Path(tmp)
        spec = f"replay:{rec_path}@{speed:g}?robot={robot}&loop=1"
        proc, url = _start(d / "db.sqlite", spec, d / "serve.err", d)
        t0 = time.monotonic()
        status: dict[str, Any] = {}
        alerts: list[dict[str, Any]] = []
        try:
            with httpx.Client(base_url=url, timeout=30) as client:
                while True:
                    time.sleep(5.0)
                    try:
                        status = client.get(f"/api/v1/robots/{robot}").json()
                        alerts = client.get(f"/api/v1/robots/{robot}/alerts").json()
                    except httpx.HTTPError:
                        continue
                    last = status.get("last_frame_t") or t_start
                    if last - t_start >= 60 * minutes or time.monotonic() - t0 > 3 * 60 * minutes / speed:
                        break
        finally:
            proc.send_signal(signal.SIGTERM)
            rc = proc.wait(60)
        st = status.get("status") or {}
        waits = [str(w.get("what", "")) for w in st.get("waiting") or ()]
        kind = st.get("baseline_kind") if status.get("has_baseline") else None
        return {
            "spec": spec.replace(str(rec_path), rec_path.name),
            "log_seconds": round((status.get("last_frame_t") or t_start) - t_start, 1),
            "wall_seconds": round(time.monotonic() - t0, 1),
            "has_baseline": kind == "topology",  # a fixed-base robot's
            "floating_baseline": kind == "floating",
            "baseline_kind": kind,
            "waiting": waits,
            "alerts": len(alerts),
            "alert_kinds": sorted({f"{a.get('kind')} {a.get('part')}" for a in alerts}),
            "errors": _errors(d / "serve.err"),
            "exit_code": rc,
        }
