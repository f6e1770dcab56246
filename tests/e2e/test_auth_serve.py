"""``bodyhealth serve`` as a process with a token: over real HTTP a mutating request without the token is
401 and with it accepted; and ``serve`` refuses a network address without a token (exit code 2)."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import httpx
import pytest

from tests.e2e.processes import serve_command, start_service, wait_answering

pytestmark = [pytest.mark.e2e]

TOKEN = "e2e-token-7f3a"
FRAMES = {
    "t": [0.0, 0.01, 0.02],
    "joint_names": ["j1"],
    "q": [[0.0], [0.1], [0.2]],
    "imu_names": ["imu0"],
    "acc": [[[0.0, 0.0, 9.81]]] * 3,
    "gyro": [[[0.0, 0.0, 0.0]]] * 3,
}


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("BODYHEALTH_API_")}
    return {**env, **extra}


def test_token_is_required_over_real_http(tmp_path: Path) -> None:
    db = f"sqlite:///{tmp_path / 'auth.db'}"
    env = _env(BODYHEALTH_API_TOKEN=TOKEN, BODYHEALTH_WORKER_INTERVAL_SECONDS="60")
    proc, url = start_service(db, err=tmp_path / "serve.err", env=env, cwd=tmp_path)
    try:
        with httpx.Client(base_url=url, timeout=10) as c:
            wait_answering(proc, c, tmp_path / "serve.err")
            frames = "/api/v1/robots/arm/frames"
            for headers in ({}, {"Authorization": "Bearer wrong"}):
                resp = c.post(frames, json=FRAMES, headers=headers)
                assert resp.status_code == 401 and resp.headers["www-authenticate"] == "Bearer"
                assert isinstance(resp.json()["detail"], str)
            assert c.get("/api/v1/robots").status_code == 401  # with a token, reads need it too
            auth = {"Authorization": f"Bearer {TOKEN}"}
            evil = c.post(frames, json=FRAMES, headers={**auth, "Origin": "https://evil.example"})
            assert evil.status_code == 403  # another site's page, even with the token
            resp = c.post(frames, json=FRAMES, headers=auth)
            assert resp.status_code == 201 and resp.json() == {"stored": 3}
            assert [r["name"] for r in c.get("/api/v1/robots", headers=auth).json()] == ["arm"]
            form = c.post(
                frames,
                content=b"t=1",
                headers={"Authorization": f"Bearer {TOKEN}", "content-type": "text/plain"},
            )
            assert form.status_code == 415
            assert c.get("/api/v1/robots", headers={"host": "evil.example"}).status_code == 400
    finally:
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(60)
    assert rc == 0


def test_serve_on_every_address_without_a_token_exits_2(tmp_path: Path) -> None:
    cmd = serve_command(0, f"sqlite:///{tmp_path / 'x.db'}", "--host", "0.0.0.0")
    done = subprocess.run(cmd, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "refusing to listen on 0.0.0.0 without an API token" in done.stderr
    assert "BODYHEALTH_API_TOKEN=" in done.stderr and "BODYHEALTH_API_TOKEN_FILE=" in done.stderr
    assert not (tmp_path / "x.db").exists()
