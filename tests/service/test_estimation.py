"""The worker's estimates in a child process (service.estimation): the same answer as in the thread,
a child that died is replaced, and a child never outlives a SIGKILLed service; the training thread's
lowered priority."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bodyschema.estimate import estimate_topology
from bodyschema.health import signal_health
from service.estimation import EstimatorProcess
from service.retrain import lower_priority
from simulators.kinematic_tree import random_robot_recording
from tests.waits import cpu_bound, wait_until

REPO = Path(__file__).resolve().parents[2]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return not (stat.exists() and stat.read_text().rsplit(")", 1)[1].split()[0] == "Z")


def _child(est: EstimatorProcess) -> int:
    pool = est._pool
    assert pool is not None
    (pid,) = pool._processes  # type: ignore[attr-defined]
    return int(pid)


def _call_in_thread(est: EstimatorProcess, fn: Any, *args: Any) -> tuple[threading.Thread, list]:
    """``est.run(fn, *args)`` on a daemon thread of its own, started; the errors it raised go in the
    list."""
    errors: list[BaseException] = []

    def call() -> None:
        try:
            est.run(fn, *args)
        except BaseException as err:
            errors.append(err)

    th = threading.Thread(target=call, daemon=True)
    th.start()
    return th, errors


def test_the_child_answers_as_the_thread_and_is_replaced_when_it_dies() -> None:
    rec = random_robot_recording(np.random.default_rng(5), n_joints=6, seconds=10.0)
    here = estimate_topology(rec, "fast", imu_delay=4.8e-3)
    with EstimatorProcess(imu_delay=4.8e-3) as est:
        there = est(rec, "fast")
        assert (there.joint_parent, there.imu_joint) == (here.joint_parent, here.imu_joint)
        assert there.joint_parent == rec.truth_parent_map and there.seconds > 0
        first = _child(est)
        os.kill(first, signal.SIGKILL)
        with pytest.raises(BrokenProcessPool):  # the estimate it died in fails, as a worker cycle would
            est(rec, "fast")
        again = est(rec, "fast")  # the next one gets a new child
        assert again.joint_parent == here.joint_parent
        assert _child(est) != first
        # the worker's other steps run in the same child, with the same answers as here
        assert est.run(os.getpid) == _child(est) != os.getpid()
        health = est.run(signal_health, rec, there)
        assert health == signal_health(rec, there)
    assert not _alive(first)


def test_abort_ends_an_estimate_in_flight_and_starts_no_other_child() -> None:
    """A stopping service does not wait for a long estimate: abort ends the child, the caller's wait
    raises at once, and the child is gone."""
    with EstimatorProcess() as est:
        first = est.run(os.getpid)
        th, errors = _call_in_thread(est, time.sleep, 60.0)
        time.sleep(0.5)  # the sleep is in the child now
        t0 = time.monotonic()
        est.abort()
        th.join(30.0)
        assert not th.is_alive() and time.monotonic() - t0 < 30.0
        assert len(errors) == 1 and isinstance(errors[0], BrokenProcessPool)
        assert not _alive(first)
        # an aborted estimator starts no other child: the stopping worker's next step fails at once
        with pytest.raises(BrokenProcessPool, match="stopped"):
            est.run(os.getpid)
        assert est._pool is None


def _half_an_answer() -> None:
    """In the child: the first bytes of an answer on the result pipe, as a child ended while it sends
    a large answer leaves the pipe (a 4-byte length, then part of the body)."""
    import gc
    import struct
    from multiprocessing.queues import SimpleQueue

    (results,) = [o for o in gc.get_objects() if isinstance(o, SimpleQueue)]
    os.write(results._writer.fileno(), struct.pack("!i", 1 << 20) + b"x" * 100)


def _stall_mid_answer() -> None:
    """Half an answer, then nothing: the child is ended from outside."""
    _half_an_answer()
    time.sleep(600.0)


def _die_mid_answer() -> None:
    """Half an answer, then the child ends on its own."""
    _half_an_answer()
    os._exit(3)


def test_a_child_that_dies_halfway_through_its_answer_fails_the_call() -> None:
    """Nobody ends this child: it dies while it sends. The caller notices that no child is alive and
    gets BrokenProcessPool within two of its one-second checks, where it would have waited for ever;
    the next call gets a new child."""
    est = EstimatorProcess()
    try:
        first = est.run(os.getpid)
        caller, errors = _call_in_thread(est, _die_mid_answer)
        # the child imports this module to find the function (seconds on a loaded machine), then dies
        caller.join(cpu_bound(60.0))
        assert not caller.is_alive(), "the call hung on the half-read answer"
        assert len(errors) == 1 and isinstance(errors[0], BrokenProcessPool)
        assert est.run(os.getpid) != first
    finally:
        est.abort()  # not close(): a pool left waiting on half an answer would hold a close for ever


def test_abort_ends_a_child_stopped_halfway_through_its_answer() -> None:
    """The pool's manager thread, halfway through reading an answer when the child ends, would wait
    for the rest for ever, and the service's stop with it: abort still returns, and the caller gets
    BrokenProcessPool."""
    est = EstimatorProcess()
    est.run(os.getpid)
    caller, errors = _call_in_thread(est, _stall_mid_answer)

    def reading_halfway() -> bool:  # the pool's manager thread waits for the rest of the answer
        return any(
            f.f_code.co_name == "_recv" and f.f_code.co_filename.endswith("connection.py")
            for f in sys._current_frames().values()
        )

    # the child imports this module to find the function, then writes
    wait_until(reading_halfway, cpu_bound(60.0), "the half-written answer")
    stopper = threading.Thread(target=est.abort, daemon=True)
    stopper.start()
    # the child's end and the pool's shutdown; a child that ignores SIGTERM is given 5 s before SIGKILL
    stopper.join(cpu_bound(15.0))
    caller.join(cpu_bound(5.0))
    assert not stopper.is_alive(), "abort hung on the half-read answer"
    assert not caller.is_alive() and len(errors) == 1 and isinstance(errors[0], BrokenProcessPool)


def test_the_childs_blas_runs_on_one_thread() -> None:
    """numpy's and scipy's BLAS in the child, each limited to one thread by the child itself: a spawned
    child starts on every core, whatever its parent set (the suite's test processes run on one thread,
    tests/conftest.py, through threadpoolctl, which no child inherits)."""
    import scipy.linalg  # noqa: F401  (scipy's BLAS, loaded here as in the child)
    from threadpoolctl import threadpool_info

    with EstimatorProcess() as est:
        blas = [d for d in est.run(threadpool_info) if d["user_api"] == "blas"]
    here = {d["filepath"] for d in threadpool_info() if d["user_api"] == "blas"}
    assert {d["filepath"] for d in blas} >= here
    assert blas and [d["num_threads"] for d in blas] == [1] * len(blas)


def test_lower_priority_raises_the_nice_value_of_the_calling_thread_only() -> None:
    seen: list[int] = []

    def train() -> None:
        lower_priority(7)
        lower_priority(3)  # never lowered again
        seen.append(os.getpriority(os.PRIO_PROCESS, 0))

    before = os.getpriority(os.PRIO_PROCESS, 0)
    t = threading.Thread(target=train)
    t.start()
    t.join()
    assert seen == [max(7, before)] and os.getpriority(os.PRIO_PROCESS, 0) == before


def test_lower_priority_moves_the_calling_thread_alone_to_the_idle_class() -> None:
    seen: list[tuple[int, int]] = []

    def train() -> None:
        lower_priority(0, idle=True)
        lower_priority(5, idle=True)  # already idle: the nice value still rises
        seen.append((os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, 0)))

    before = os.sched_getscheduler(0)
    t = threading.Thread(target=train)
    t.start()
    t.join()
    assert before == os.SCHED_OTHER and os.sched_getscheduler(0) == before
    assert seen == [(os.SCHED_IDLE, max(5, os.getpriority(os.PRIO_PROCESS, 0)))]


@pytest.mark.slow
def test_the_child_ends_with_a_sigkilled_parent(tmp_path: Path) -> None:
    script = tmp_path / "parent.py"
    script.write_text(
        textwrap.dedent(
            """
            import os, signal, sys
            import numpy as np
            from service.estimation import EstimatorProcess
            from simulators.kinematic_tree import random_robot_recording

            if __name__ == "__main__":
                est = EstimatorProcess()
                est(random_robot_recording(np.random.default_rng(0), n_joints=3, seconds=5.0), "fast")
                (child,) = est._pool._processes
                with open(f"/proc/{child}/stat") as stat:
                    server = stat.read().rsplit(")", 1)[1].split()[1]
                print(child, server, os.getpid(), flush=True)
                os.kill(os.getpid(), signal.SIGKILL)
            """
        )
    )
    proc = subprocess.run(
        [sys.executable, str(script)], cwd=REPO, capture_output=True, text=True, timeout=120, check=False
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    # the child and its parent, the fork server: the child ends as the service does (a pidfd wakes
    # it), and then the server, whom no process can ask for a child any more
    child, server, parent = map(int, proc.stdout.split())
    assert server != parent  # a fork of the fork server, not of the service
    deadline = time.monotonic() + cpu_bound(10)
    while (_alive(child) or _alive(server)) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(child) and not _alive(server)


def test_the_service_runs_the_workers_cpu_bound_steps_in_the_estimators_child(tmp_path: Path) -> None:
    """``bodyhealth serve`` (its :class:`~service.daemon.Daemon`) hands the worker's other CPU-bound
    steps to the estimator's child: they run in that process, not under the API's interpreter lock."""
    from service.daemon import Daemon
    from service.settings import Settings

    settings = Settings(database_url=f"sqlite:///{tmp_path / 'serve.db'}", dask_enabled=False)
    daemon = Daemon(settings)
    daemon.start()
    try:
        assert daemon.worker is not None
        child = daemon.worker.compute(os.getpid)
        assert child != os.getpid() and daemon.worker.compute(os.getpid) == child  # one child, kept
    finally:
        daemon.stop()
