"""The suite's trust rules hold: a skip fails under ``BODYHEALTH_CI=1``, seeds are fixed per test, and
every collected test has an id of its own (xdist runs tests by id).

Each case runs a throw-away test file in a child pytest that loads this suite's ``tests/conftest.py``
as a plugin, so the real hooks are exercised, not a copy of them.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SKIPPING = """
import pytest

def test_needs_a_server():
    pytest.skip("no server here")

def test_plain():
    assert 1 + 1 == 2
"""

SEEDED = """
def test_draws(seed, rng):
    print("DRAW", seed, float(rng.random()))
"""


OPERATIONS = """
import schemathesis
from fastapi import FastAPI

app = FastAPI()

@app.get("/a")
def a() -> dict:
    return {}

@app.get("/b")
def b() -> dict:
    return {}

schema = schemathesis.openapi.from_asgi("/openapi.json", app)

@schema.parametrize()
def test_operation(case):
    pass
"""

#: A plugin that gives the second test the first one's id, as a collector that names its items badly would.
SAME_ID = """
import pytest

@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items):
    items[1]._id = items[0]._id
"""


def _child_pytest(tmp_path: Path, source: str, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    (tmp_path / "test_child.py").write_text(source)
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    child_env = {k: v for k, v in os.environ.items() if k not in ("BODYHEALTH_CI", "BODYHEALTH_TEST_SEED")}
    child_env.update(env)
    child_env["PYTHONPATH"] = str(ROOT)
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "tests.conftest", "-c", str(tmp_path / "pytest.ini"),
         "-s", "-q", "-p", "no:cacheprovider", *args, str(tmp_path / "test_child.py")],
        cwd=tmp_path, env=child_env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_a_skip_is_a_failure_under_ci(tmp_path: Path) -> None:
    res = _child_pytest(tmp_path, SKIPPING, BODYHEALTH_CI="1")
    assert res.returncode == 1, res.stdout
    assert "1 failed, 1 passed" in res.stdout
    assert "skipped under BODYHEALTH_CI=1" in res.stdout and "no server here" in res.stdout


def test_a_skip_stays_a_skip_outside_ci(tmp_path: Path) -> None:
    res = _child_pytest(tmp_path, SKIPPING)
    assert res.returncode == 0, res.stdout
    assert "1 passed, 1 skipped" in res.stdout


def _draw(tmp_path: Path, **env: str) -> str:
    res = _child_pytest(tmp_path, SEEDED, **env)
    assert res.returncode == 0, res.stdout
    return next(line for line in res.stdout.splitlines() if "DRAW" in line)


@pytest.mark.slow
def test_seeds_are_fixed_per_test_and_can_be_pinned(tmp_path: Path) -> None:
    first, second = _draw(tmp_path), _draw(tmp_path)
    assert first == second
    pinned = _draw(tmp_path, BODYHEALTH_TEST_SEED="12345")
    assert pinned.split()[1] == "12345" and pinned != first


def test_each_api_operation_is_a_test_with_its_own_id(tmp_path: Path) -> None:
    res = _child_pytest(tmp_path, OPERATIONS, "--co")
    assert res.returncode == 0, res.stdout
    ids = [line for line in res.stdout.splitlines() if "::" in line]
    assert ids == ["test_child.py::test_operation[GET /a]", "test_child.py::test_operation[GET /b]"]


def test_a_repeated_test_id_fails_collection(tmp_path: Path) -> None:
    (tmp_path / "same_id.py").write_text(SAME_ID)
    res = _child_pytest(tmp_path, SKIPPING, "-p", "same_id")  # cwd is on the path of `python -m`
    assert res.returncode != 0, res.stdout
    assert "collected more than once" in res.stdout + res.stderr
