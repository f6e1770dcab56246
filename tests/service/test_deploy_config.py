"""The compose stack and the image are safe by default: no container engine runs here, so the files are
read and every property that matters is asserted, and the Dask command lines run as plain processes.

Held: the API is published on the loopback address only; no secret is written in the repository (every
one comes from ``.env``, which git ignores, with ``.env.example`` naming each); the service gets a token,
which ``serve`` needs on a non-loopback address; every container restarts unless stopped and has a
healthcheck; the image runs as an unprivileged user.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.ports import free_port

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]
_VAR = re.compile(r"\$\{([A-Z_][A-Z0-9_]*)(:?[-?][^}]*)?\}")


def test_api_published_on_loopback_only() -> None:
    ports = [p for svc in SERVICES.values() for p in svc.get("ports", [])]
    assert ports == ["127.0.0.1:8000:8000"]


def test_no_secret_in_the_repository() -> None:
    for svc in SERVICES.values():
        for key, value in (svc.get("environment") or {}).items():
            if "PASSWORD" in key or "TOKEN" in key:
                assert _VAR.fullmatch(str(value)), f"{key} must come from .env, got {value!r}"
            if key.endswith("DATABASE_URL"):
                password = str(value).split("//", 1)[1].split("@", 1)[0].split(":", 1)[1]
                assert _VAR.fullmatch(password), f"{key} holds a literal password"


def test_required_secrets_fail_fast_and_are_in_the_example() -> None:
    text = (ROOT / "docker-compose.yml").read_text()
    required = {m.group(1) for m in _VAR.finditer(text) if (m.group(2) or "").startswith(":?")}
    assert required == {"BODYHEALTH_DB_PASSWORD", "BODYHEALTH_API_TOKEN"}
    example = (ROOT / ".env.example").read_text()
    named = {line.split("=", 1)[0] for line in example.splitlines() if line and not line.startswith("#")}
    assert {m.group(1) for m in _VAR.finditer(text)} <= named
    assert ".env" in (ROOT / ".gitignore").read_text().split()


def test_service_gets_a_token_and_binds_all_addresses() -> None:
    svc = SERVICES["service"]
    assert "0.0.0.0" in svc["command"]
    assert "BODYHEALTH_API_TOKEN" in svc["environment"]


def test_restart_policy_and_healthchecks() -> None:
    assert {name: svc.get("restart") for name, svc in SERVICES.items()} == {
        name: "unless-stopped" for name in SERVICES
    }
    assert all("test" in svc.get("healthcheck", {}) for svc in SERVICES.values())


def test_distributed_training_layout() -> None:
    """A Dask scheduler, two workers and the service, all from the one image; the service sends its
    retrains to the scheduler, and the workers reach the database the windows are read from."""
    images = {name: svc.get("image") for name, svc in SERVICES.items() if name != "db"}
    assert set(images) == {"scheduler", "worker-1", "worker-2", "service"}
    assert set(images.values()) == {"bodyhealth:local"}
    assert SERVICES["scheduler"]["command"][:2] == ["dask", "scheduler"]
    for name in ("worker-1", "worker-2"):
        worker = SERVICES[name]
        assert worker["command"][:3] == ["dask", "worker", "tcp://scheduler:8786"]
        assert set(worker["depends_on"]) == {"scheduler", "db"}
        assert "ports" not in worker
    assert SERVICES["service"]["environment"]["BODYHEALTH_DASK_SCHEDULER"] == "tcp://scheduler:8786"
    assert "8786" not in str([p for svc in SERVICES.values() for p in svc.get("ports", [])])


@pytest.mark.slow
def test_compose_dask_commands_start_a_cluster_whose_workers_preload_the_training_code() -> None:
    """The scheduler's and a worker's command lines, as compose runs them (the compose host names and
    ports swapped for loopback ones), run here as real processes: the worker joins, with the training
    code imported before its first task (``--preload service.worker_preload``)."""
    from distributed import Client

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"

    def local(command: list[str]) -> list[str]:
        swap = {"tcp://scheduler:8786": address, "0.0.0.0": "127.0.0.1", "8786": str(port)}
        bin_dir = Path(sys.executable).parent
        return [str(bin_dir / command[0]), *(swap.get(word, word) for word in command[1:])]

    def loaded() -> tuple[bool, bool]:  # a closure: shipped to the worker by value
        return "bodyschema.estimate" in sys.modules, "service.store" in sys.modules

    procs = [subprocess.Popen(local(SERVICES["scheduler"]["command"]), cwd=ROOT)]
    try:
        time.sleep(1.0)
        procs.append(subprocess.Popen(local(SERVICES["worker-1"]["command"]), cwd=ROOT))
        with Client(address, timeout=30) as client:
            client.wait_for_workers(1, timeout=90)
            assert list(client.run(loaded).values()) == [(True, True)]
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_image_runs_unprivileged() -> None:
    lines = [line.split() for line in (ROOT / "Dockerfile").read_text().splitlines() if line.strip()]
    users = [words[1] for words in lines if words[0] == "USER"]
    assert users and users[-1] not in ("root", "0")
    last_run = max(i for i, words in enumerate(lines) if words[0] == "RUN")
    assert max(i for i, words in enumerate(lines) if words[0] == "USER") > last_run
