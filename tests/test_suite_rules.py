"""The suite's trust rules hold: a skip fails under ``BODYHEALTH_CI=1``, seeds are fixed per test,
every collected test has an id of its own (xdist runs tests by id), and no test file imports another
one: what several test files share lives in a module of its own (tests/builders.py,
tests/service/builders.py, a conftest.py for fixtures), so each test file can be changed, split or
dropped on its own.

Each case runs a throw-away test file in a child pytest that loads this suite's ``tests/conftest.py``
as a plugin, so the real hooks are exercised, not a copy of them.
"""

from __future__ import annotations

import ast
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
    # the outer run's options are not the child's: PYTEST_ADDOPTS="-vv" made its --co print a tree
    outer = ("BODYHEALTH_CI", "BODYHEALTH_TEST_SEED", "PYTEST_ADDOPTS")
    child_env = {k: v for k, v in os.environ.items() if k not in outer}
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


#: Test files that still import another one, and which: a file is dropped from here once it takes what it
#: needs from a shared module.
IMPORTS_A_TEST_FILE: dict[str, set[str]] = {}


def imported_test_modules(source: str, module: str) -> set[str]:
    """The ``tests.*.test_*`` modules that ``source`` (the text of module ``module``, dotted) imports,
    in any form: ``import a.test_b``, ``from a.test_b import x``, ``from a import test_b``, relative."""
    package = module.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parent, base] if base else parent)
            names = [base, *(f"{base}.{alias.name}" for alias in node.names)]
        else:
            continue
        found |= {n for n in names if n.startswith("tests.") and n.rsplit(".", 1)[-1].startswith("test_")}
    return found


def test_the_import_check_sees_every_form() -> None:
    here = "tests.service.test_x"
    assert imported_test_modules("from tests.service.test_worker import feed", here) == {
        "tests.service.test_worker"
    }
    assert imported_test_modules("import tests.bodyschema.test_health as h", here) == {
        "tests.bodyschema.test_health"
    }
    assert imported_test_modules("from tests.e2e import test_dashboard", here) == {"tests.e2e.test_dashboard"}
    assert imported_test_modules("from .test_api import batch", here) == {"tests.service.test_api"}
    assert imported_test_modules("from ..bodyschema.test_outtree import trees", here) == {
        "tests.bodyschema.test_outtree"
    }
    def_inside = "def f():\n    from tests.bodyschema.test_health import synth\n"
    assert imported_test_modules(def_inside, here) == {"tests.bodyschema.test_health"}
    shared = "from tests.service.builders import feed\nfrom fastapi.testclient import TestClient\n"
    assert imported_test_modules(shared, here) == set()


def test_no_test_file_imports_another() -> None:
    offenders: dict[str, set[str]] = {}
    for path in sorted((ROOT / "tests").rglob("*.py")):
        rel = path.relative_to(ROOT)
        module = ".".join(rel.with_suffix("").parts)
        got = imported_test_modules(path.read_text(encoding="utf-8"), module)
        got -= IMPORTS_A_TEST_FILE.get(rel.as_posix(), set())
        if got:
            offenders[rel.as_posix()] = got
    assert offenders == {}, "move what these take from a test file into a shared module: " + repr(offenders)


def test_the_hung_test_limit_stretches_with_the_load(request: pytest.FixtureRequest) -> None:
    """pytest-timeout's 600 s is an idle machine's bound; the conftest stretches it by the load at
    the test's start, as every wait of the suite is (tests/waits.py), so busy loops beside the suite
    make a slow test slower, not a failure."""
    mark = request.node.get_closest_marker("timeout")
    idle = float(request.config.getini("timeout"))
    assert idle == 600.0 and mark is not None
    assert mark.args[0] >= idle
    # the load average only moves slowly: the limit is the idle bound times the share now, within 20 %
    share = max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1))
    assert 0.8 * idle * share <= mark.args[0] <= 1.25 * idle * share
