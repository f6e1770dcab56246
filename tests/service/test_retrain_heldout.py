"""``Settings.network_heldout_check``: the service's network retrains test their tree against its
rivals on held-out data (bodyschema.network_confidence) when it is set (the default), on the cluster's
task and in the worker's own estimator (inline or in its child process) alike, and not when it is
switched off.

The window: the synthetic three-joint arm with j3 held still (tests/builders.py), read back from a
real SQLite store. The networks alone call its tree unique; with the check no part stands, the
joints to move are named and the rival trees listed.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.estimation import EstimatorProcess
from service.retrain import NetworkOptions, TrainingOptions
from service.retrain.task import RetrainJob, run_retrain
from service.settings import Settings
from service.store import open_store
from service.worker import Worker
from tests.builders import synth
from tests.service.builders import feed

pytestmark = pytest.mark.slow

WINDOW = 20.0
NETWORK = NetworkOptions(seed=5, epochs=20)


@pytest.fixture(scope="module")
def window(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, float]:
    """A store holding one window of the arm with j3 locked: its URL and the window's end."""
    url = f"sqlite:///{tmp_path_factory.mktemp('heldout') / 'w.db'}"
    with open_store(url) as store:
        end = feed(store, synth(np.random.default_rng(3), seconds=WINDOW, locked="j3")) - 0.01
    return url, end


def test_the_setting_reaches_the_training_options() -> None:
    """On by default; an explicit false in the settings or in the options given is kept."""
    default = Settings(database_url="sqlite://")
    off = Settings(database_url="sqlite://", network_heldout_check=False)
    assert TrainingOptions.from_settings(default).heldout_check is True
    assert TrainingOptions.from_settings(off).heldout_check is False
    assert TrainingOptions.from_settings(off, TrainingOptions(heldout_check=True)).heldout_check is True
    assert TrainingOptions.from_settings(default, TrainingOptions(heldout_check=False)).heldout_check is False


def test_a_retrain_task_with_the_check_leaves_an_undecided_window_undetermined(
    window: tuple[str, float],
) -> None:
    """The cluster's task body (what a Dask worker runs), on the window read back from the store."""
    url, end = window

    def retrain(check: bool) -> dict:
        job = RetrainJob(url, "arm", "network", end, WINDOW, network=NETWORK, heldout_check=check)
        return run_retrain(job).topology

    plain, checked = retrain(False), retrain(True)
    assert plain["unique"] is True and "candidates" not in plain
    assert plain["insufficient_excitation"] == ["j3"]
    assert max(plain["confidence"].values()) > 0.99  # the networks' own margins: sure of most parts
    assert checked["unique"] is False
    assert checked["insufficient_excitation"] == ["j1", "j2", "j3"]
    assert len(checked["candidates"]) >= 1
    assert set(checked["confidence"]) == set(plain["confidence"])
    assert max(checked["confidence"].values()) <= 0.5  # j3 could hang anywhere: no part stands


def test_the_workers_own_estimator_takes_the_setting(window: tuple[str, float]) -> None:
    url, end = window
    settings = Settings(database_url=url, window_seconds=WINDOW)  # the check is on by default
    with open_store(url) as store:
        rec = store.read_window("arm", WINDOW, end=end, epoch=0)
        worker = Worker(store, settings)
        assert rec is not None
        topo = worker.estimator(rec, "network")
    assert not topo.unique and set(topo.undetermined) == {"j1", "j2", "j3"} and topo.candidates


def test_the_estimating_child_takes_the_setting(window: tuple[str, float]) -> None:
    """The service's estimates run in a child process (service.estimation): the check goes with them."""
    url, end = window
    with open_store(url) as store:
        rec = store.read_window("arm", WINDOW, end=end, epoch=0)
    assert rec is not None
    with EstimatorProcess() as estimate:  # the check is on by default
        topo = estimate(rec, "network")
    assert not topo.unique and set(topo.undetermined) == {"j1", "j2", "j3"} and topo.candidates
