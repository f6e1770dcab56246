"""Shared fixtures and the suite's two trust rules.

**Every random test is reproducible.** The ``seed`` fixture is a fixed function of the test's id
(CRC-32 of the node id), so a test draws the same cases on every run and on every machine; a test can
only fail because the code changed. ``BODYHEALTH_TEST_SEED=<n>`` pins every test to one seed, and
``BODYHEALTH_TEST_SEED=random`` draws fresh ones (printed, for exploring, never for CI). Python's
``random``, NumPy's legacy global generator and torch's generator (when torch is loaded) are seeded the
same way before each test, so code that forgets to take an ``rng`` is reproducible too. Hypothesis runs
derandomized (its examples are a function of the test) and keeps no example database between runs.

**Every collected test runs once, under its own id.** The suite runs on pytest-xdist workers
(``make test``), which schedule tests by node id: two tests with one id would run as one, and the other
would vanish from the count without a failure. Collection fails on a repeated id. schemathesis names
one test per API operation (``test_x[GET /path]``), but pytest >= 9.2 builds the node id from the
function's name and its parametrization only, so its tests all share one id: the operation is put back
into it.

**A skip is a failure in CI.** Under ``BODYHEALTH_CI=1`` (``.ci/run`` sets it) a test that skips —
because PostgreSQL, the browser or the BROAD data is missing — is reported as failed, so a missing part
can never turn CI green.
"""

from __future__ import annotations

import os
import random
import sys
import zlib
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import settings as hypothesis_settings

from bodyschema.threads import set_blas_threads

__all__ = ["NETWORK_SCHEDULE_ENV", "TRAINING_IDLE_ENV", "node_seed"]

CI_ENV = "BODYHEALTH_CI"
SEED_ENV = "BODYHEALTH_TEST_SEED"

#: The sensor-network schedule is on in the product (``Settings.network_interval_cycles``: once a
#: minute per robot). The suite's worker, API and serve tests judge the fast screen, its alerts and
#: their latency in worker cycles, with scripted estimators whose calls they count; a network retrain
#: every twelfth cycle would add tens of CPU seconds to them on a 2-core machine and change what they
#: count. So the suite turns the schedule off unless a test sets it: the schedule, the trigger on a
#: new finding and the warm starts are tested where they are the subject (tests/service/
#: test_worker.py, tests/service/test_dask_training.py, tests/bodyschema/test_network_warm_start.py),
#: and the default itself in tests/service/test_settings.py.
NETWORK_SCHEDULE_ENV = "BODYHEALTH_NETWORK_INTERVAL_CYCLES"
os.environ.setdefault(NETWORK_SCHEDULE_ENV, "0")

#: The embedded cluster's retrains run in Linux's idle scheduling class in the product
#: (``Settings.training_idle``), so they never delay the API and ingest. A thread of that class gets a
#: few thousandths of a core beside normal-priority work that fills every core, which is what the
#: suite is beside on a busy machine: a retrain a test waits on would never end (the fleet bench's
#: test still ran after 15 minutes beside two busy loops; niced, 87 s). So the suite's retrains run
#: niced (``training_nice``) and still yield, unless a test sets the class: the class itself is tested
#: in tests/service/test_estimation.py, and the default in tests/service/test_settings.py.
TRAINING_IDLE_ENV = "BODYHEALTH_TRAINING_IDLE"
os.environ.setdefault(TRAINING_IDLE_ENV, "0")

hypothesis_settings.register_profile("bodyhealth", derandomize=True, database=None, print_blob=True)
hypothesis_settings.load_profile("bodyhealth")

#: The suite's workers share the cores (``make test``: one per core), and they run the worker's fits in
#: their own process where the service runs them in its one-thread estimator child
#: (:mod:`service.estimation`). BLAS on every core in each of them spin-waits against the other: the
#: geometry drift run took 93 s beside the damage suite, against 18 s alone. So each test process fits
#: on one thread, as the service does.
set_blas_threads(1)


def node_seed(nodeid: str) -> int:
    """The fixed seed of a test: CRC-32 of its node id, or ``BODYHEALTH_TEST_SEED`` when set.

    >>> node_seed("tests/test_x.py::test_y") == node_seed("tests/test_x.py::test_y")
    True
    >>> node_seed("tests/test_x.py::test_y") != node_seed("tests/test_x.py::test_z")
    True
    """
    pinned = os.environ.get(SEED_ENV, "")
    if pinned == "random":
        return random.SystemRandom().randrange(2**31)
    if pinned:
        return int(pinned)
    return zlib.crc32(nodeid.encode()) & 0x7FFFFFFF


def _in_ci() -> bool:
    return os.environ.get(CI_ENV, "") not in ("", "0")


@pytest.fixture
def seed(request: pytest.FixtureRequest) -> int:
    """This test's fixed seed, printed so a failure can be replayed with ``BODYHEALTH_TEST_SEED``."""
    value = node_seed(request.node.nodeid)
    print(f"{request.node.nodeid}: seed={value} (replay with {SEED_ENV}={value})")
    return value


@pytest.fixture
def rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


@pytest.fixture(autouse=True)
def _seed_global_generators(request: pytest.FixtureRequest) -> Iterator[None]:
    """Seed the global generators per test, so code that draws without an ``rng`` repeats too."""
    value = node_seed(request.node.nodeid)
    random.seed(value)
    np.random.seed(value)  # noqa: NPY002 - the legacy global generator is exactly what is pinned here
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.manual_seed(value)
    yield


def _ci_failure(report: pytest.TestReport | pytest.CollectReport) -> None:
    """Turn a skip report into a failure that says why (under ``BODYHEALTH_CI``)."""
    reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
    report.outcome = "failed"
    report.longrepr = f"skipped under {CI_ENV}=1, where every test must run: {reason}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    outcome = yield
    report = outcome.get_result()
    if _in_ci() and report.skipped and not hasattr(report, "wasxfail"):
        _ci_failure(report)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Iterator[None]:
    outcome = yield
    report = outcome.get_result()
    if _in_ci() and report.skipped:
        _ci_failure(report)


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item) -> Iterator[None]:
    """pytest-timeout's limit (``timeout`` in pyproject.toml, or a test's own ``timeout`` mark: what
    a hung test may take on an idle machine) stretched by the load at the test's start
    (:func:`tests.waits.cpu_bound`): a busy machine makes a test slower, never failing. Runs before
    pytest-timeout's own wrapper, which reads the mark."""
    from tests.waits import cpu_bound

    mark = item.get_closest_marker("timeout")
    base = mark.args[0] if mark is not None and mark.args else item.config.getini("timeout")
    if base:
        item.add_marker(pytest.mark.timeout(cpu_bound(float(base))), append=False)
    yield


def _operation_ids(items: list[pytest.Item]) -> None:
    """Put schemathesis' operation label into its tests' node ids (see the module docstring).

    pytest keeps the node id in ``_id`` and offers no setter; the name the plugin gave the item
    (``test_x[GET /path]``) is what the id should end with.
    """
    for item in items:
        if getattr(item, "operation_label", None) and not item.nodeid.endswith("]"):
            item._id = item.parent.id.child(item.name)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    _operation_ids(items)
    seen: set[str] = set()
    repeated = sorted({item.nodeid for item in items if item.nodeid in seen or seen.add(item.nodeid)})
    if repeated:
        raise pytest.UsageError(
            f"{len(repeated)} test id(s) collected more than once (xdist would run only one of each): "
            + ", ".join(repeated[:5])
        )
