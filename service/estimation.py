"""The worker's estimates in a child process: CPU-bound work off the API's interpreter lock.

The API, the ingest writer and the worker share one process (:mod:`service.daemon`). A fast estimate
of one robot's window is 0.1 to 1 CPU s of numpy and Python; in the worker thread it holds the
interpreter lock for most of that, and every request that arrives meanwhile waits for it: the latency
tail of docs/bench/load.md. In a child process it costs the service only the pickling of the window
and of the answer. The worker's other CPU-bound steps (signal health, impact removal, fingerprints) run
there too (:meth:`EstimatorProcess.run`): in the worker thread they held the lock for a tenth of the
service's time, long enough to triple the API's latency tail. The child is started on the first estimate
(:mod:`service.children`: a fork of the fork server, and it ends with the service) and serves one
estimate at a time, in order.

A child that dies is replaced at the next call; the call it died in raises, the worker logs it for that
robot, and the next cycle tries again. The network methods come here only when the service runs
without a training cluster (:mod:`service.retrain`); with one, they train there.

>>> import numpy as np
>>> from bodyschema.recording import Recording
>>> t = np.arange(400) / 100.0
>>> q = np.sin(np.stack([t, 1.3 * t], axis=1))
>>> qd = np.cos(np.stack([t, 1.3 * t], axis=1)) * np.array([1.0, 1.3])
>>> gyro = np.zeros((400, 2, 3))
>>> gyro[:, 0, 2], gyro[:, 1, 2] = qd[:, 0], qd[:, 0] + qd[:, 1]
>>> rec = Recording(t=t, joint_names=("a", "b"), q=q, qd=qd, imu_names=("i0", "i1"),
...                 acc=np.zeros((400, 2, 3)), gyro=gyro)
>>> with EstimatorProcess() as estimate:
...     topo = estimate(rec, "fast")
>>> topo.joint_parent, topo.imu_joint
({'a': None, 'b': 'a'}, {'i0': 'a', 'i1': 'b'})
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from types import TracebackType
from typing import Any, TypeVar

from bodyschema.recording import Recording
from bodyschema.topology import Topology
from service.children import CHILDREN, exit_with_service

__all__ = ["EstimatorProcess", "default_estimator"]

T = TypeVar("T")


def _start_child(service: int) -> None:
    """The child's setup: it ends with the service, and its fits run BLAS on one thread. They are tall
    and thin least squares; on more threads they spin against the service and the training workers
    for the same cores (:func:`bodyschema.threads.set_blas_threads`)."""
    from bodyschema.threads import set_blas_threads

    exit_with_service(service)
    set_blas_threads(1)


def default_estimator(
    rec: Recording, method: str, imu_delay: float | None = None, heldout_check: bool = True
) -> Topology:
    """:func:`~bodyschema.estimate.estimate_topology` timed in CPU seconds; ``imu_delay`` (s) is the
    IMUs' stated filter delay (``Settings.imu_filter_delay_ms``), taken out of the lag for the skew;
    ``heldout_check`` tests a network method's tree on held-out data (``Settings.network_heldout_check``)."""
    from bodyschema.estimate import estimate_topology  # heavy (torch) only when first needed

    return estimate_topology(
        rec, method=method, timer=time.process_time, imu_delay=imu_delay, heldout_check=heldout_check
    )


#: Seconds a terminated child is given to end before it is killed (it has no handler to run).
_END_S = 5.0


def _children(pool: ProcessPoolExecutor) -> list[Any]:
    """``pool``'s child processes. ProcessPoolExecutor ends busy children only from Python 3.14
    (terminate_workers), and tells whether they live not at all; until then its private process table
    is the one handle on them (empty once the pool is shut down)."""
    return list((getattr(pool, "_processes", None) or {}).values())


def _unblock_result_reader(pool: ProcessPoolExecutor) -> None:
    """Close this process's write end of ``pool``'s result pipe, once its children are gone.

    A child ended while it sends its answer leaves part of a message in the pipe, and the pool's
    manager thread waits for the rest for ever: ``shutdown`` then never returns (a SIGTERM that did not
    stop the service, its estimating child a zombie). With the children gone this process holds the
    pipe's only write end, so closing it turns that wait into end-of-file, which the manager takes for
    a broken pool. The pool's attributes are private; CPython 3.11 to 3.13 name them so, and where they
    are missing there is nothing to close."""
    queue = getattr(pool, "_result_queue", None)
    writer = getattr(queue, "_writer", None)
    if writer is not None:
        with contextlib.suppress(OSError):
            writer.close()


#: How often a caller waiting for an answer checks that the child is still there, s.
_POLL_S = 1.0


def _answer(pool: ProcessPoolExecutor, future: Future[T]) -> T:
    """``future``'s result. A child that died on its own (the OOM killer, say) breaks the pool, and
    the call raises ``BrokenProcessPool``; but one that died halfway through sending its answer leaves
    the pool's reader waiting for the rest (:func:`_unblock_result_reader`), and the caller with it.
    So while it waits, the caller checks once a second that a child is alive; once none is, it
    gives the pool one more second to notice, then unblocks the reader itself."""
    gone_since: float | None = None
    while True:
        try:
            return future.result(timeout=_POLL_S)
        except TimeoutError:
            pass
        if any(p.is_alive() for p in _children(pool)):
            gone_since = None
        elif gone_since is None:
            gone_since = time.monotonic()
        elif time.monotonic() - gone_since >= _POLL_S:
            _unblock_result_reader(pool)


class EstimatorProcess:
    """An :data:`~service.worker.Estimator` that runs :func:`default_estimator` in a child process
    (module doc), with the IMUs' stated filter delay ``imu_delay`` (s) and the networks' held-out test
    ``heldout_check``."""

    def __init__(self, imu_delay: float | None = None, heldout_check: bool = True) -> None:
        self.imu_delay = imu_delay
        self.heldout_check = heldout_check
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self._aborted = False

    def __call__(self, rec: Recording, method: str) -> Topology:
        return self.run(default_estimator, rec, method, self.imu_delay, self.heldout_check)

    def run(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> T:
        """``fn(*args, **kwargs)`` in the child (a module-level function, picklable arguments): the
        worker's other CPU-bound steps go this way too (:data:`service.worker.Compute`)."""
        pool = self._ensure()
        try:
            return _answer(pool, pool.submit(fn, *args, **kwargs))
        except BrokenProcessPool:
            with self._lock:  # the child died: the next call starts another
                if self._pool is pool:
                    self._pool = None
            pool.shutdown(wait=False, cancel_futures=True)
            raise

    def _ensure(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._aborted:
                raise BrokenProcessPool("the estimator was stopped")
            if self._pool is None:
                self._pool = ProcessPoolExecutor(
                    max_workers=1, mp_context=CHILDREN, initializer=_start_child, initargs=(os.getpid(),)
                )
            return self._pool

    def close(self) -> None:
        """End the child (idempotent); an estimate in flight is waited for."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)

    def abort(self) -> None:
        """End the child now, an estimate in flight with it: its caller gets ``BrokenProcessPool``, and
        so does every later call. A stopping service uses it so that SIGTERM is not held by a long
        estimate, nor by a new child (its fork server may still be importing on a loaded machine) for
        the next step of the robot the worker is finishing."""
        with self._lock:
            self._aborted = True
            pool, self._pool = self._pool, None
        if pool is None:
            return
        procs = _children(pool)
        for proc in procs:
            with contextlib.suppress(OSError):
                proc.terminate()
        for proc in procs:
            proc.join(_END_S)
            if proc.is_alive():
                proc.kill()
                proc.join(_END_S)
        _unblock_result_reader(pool)
        pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> EstimatorProcess:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
