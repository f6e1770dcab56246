"""One sensor-network retrain as a task that runs in another process (a Dask worker).

The scheduler and the network carry only a :class:`RetrainJob`: the database URL, the robot, the
window's reference (device clock epoch, end, length), the method and how its networks train
(:class:`~bodyschema.network_options.NetworkOptions`). Never arrays: the task
opens the store itself (an SQLite file in WAL mode is read by other processes while the service
writes it; PostgreSQL anyway), reads the window, drops the samples around encoder impacts as the
worker does, runs :func:`bodyschema.estimate.estimate_topology` and returns a :class:`RetrainResult`
(plain data: the topology JSON and what it cost).

The task only reads the database. Storing the result is the service's job, when it collects the
finished future: a task that Dask runs twice (its worker died half-way) still yields one future and
one stored row. :func:`job_key` is the task's Dask key, a function of (robot, method, epoch, window end),
so the same job submitted again while it is known to the scheduler is recognised as the same task.

Example
-------
>>> job = RetrainJob("sqlite:///var/x.db", "arm", "network", window_end=12.5, window_seconds=10.0)
>>> job_key(job)
'retrain-network-arm-e0-12.500000'
"""

from __future__ import annotations

import functools
import os
import socket
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from bodyschema.network_options import NetworkOptions

if TYPE_CHECKING:
    from bodyschema.estimate import TopologyFit
    from bodyschema.recording import Recording
    from bodyschema.topology import Topology

__all__ = [
    "WARM_METHODS",
    "RetrainJob",
    "RetrainResult",
    "WindowGone",
    "job_key",
    "run_retrain",
    "shareable_url",
]

#: The methods whose training can start from stored weights (the sensor networks; the MLP baseline
#: keeps the paper's fixed budget from random weights).
WARM_METHODS: tuple[str, ...] = ("network", "network-paper")


class WindowGone(LookupError):
    """The job's window holds too little data (pruned, or the robot was removed) to train on."""


@dataclass(frozen=True)
class RetrainJob:
    """What one retrain needs, all of it small: the task reads the data itself.

    ``network``: how the networks train (its ``seed`` seeds their initialization and batches);
    ``imu_delay``: the IMUs' stated filter delay, s (:func:`bodyschema.estimate.fit_topology`).
    """

    database_url: str
    robot: str
    method: str
    window_end: float
    window_seconds: float
    epoch: int = 0
    network: NetworkOptions = field(default_factory=NetworkOptions)
    imu_delay: float | None = None
    min_samples: int = 50
    #: the baseline current at submission: the task starts from the robot's weights trained under it
    baseline_id: int | None = None
    warm_start: bool = True
    #: nice value the training thread is raised to (0: left as it is); see :func:`lower_priority`
    nice: int = 0
    #: the training thread runs under Linux's idle scheduling class (:func:`lower_priority`)
    idle: bool = False
    #: the encoder stamps are moved by this lag (s) first, and the move put back into the timing
    #: reported (:func:`bodyschema.timing.lag_hinted`; 0: not moved)
    lag_hint: float = 0.0
    #: the networks' tree tested against its rivals on held-out data
    #: (:func:`bodyschema.network_confidence.heldout_check`)
    heldout_check: bool = True


@dataclass(frozen=True)
class RetrainResult:
    """A finished retrain: the topology JSON (docs/design.md, 'Topology JSON') and what it cost where it
    ran."""

    key: str
    robot: str
    method: str
    window_end: float
    topology: dict[str, Any]
    cpu_seconds: float
    wall_seconds: float
    epochs: float | None
    converged: bool | None
    pid: int
    host: str
    extra: dict[str, Any] = field(default_factory=dict)
    #: the trained networks (:func:`service.store.weights.pack_weights`), for the next warm start
    weights: bytes | None = None
    #: the version of the robot's stored weights training began from (None: a cold start)
    warm_from: int | None = None
    baseline_id: int | None = None
    imus: tuple[str, ...] = ()
    joints: tuple[str, ...] = ()


def shareable_url(url: str) -> str | None:
    """``url`` as another process opens the same database: an SQLite file by its absolute path (a
    worker's working directory may differ); None for an in-memory database, which no other process
    can open.

    >>> shareable_url("sqlite://") is None, shareable_url("postgresql+psycopg://u@h/db")
    (True, 'postgresql+psycopg://u@h/db')
    >>> shareable_url("sqlite:////srv/x.db")
    'sqlite:////srv/x.db'
    """
    from sqlalchemy.engine import make_url

    from service.store.identity import sqlite_file

    u = make_url(url)
    if u.get_backend_name() != "sqlite":
        return url
    path = sqlite_file(url)
    if path is None:
        return None
    return u.set(database=str(path)).render_as_string(hide_password=False)


def job_key(job: RetrainJob) -> str:
    """The Dask key of ``job``: one per robot, method, device clock epoch and window end."""
    return f"retrain-{job.method}-{job.robot}-e{job.epoch}-{job.window_end:.6f}"


def lower_priority(nice: int, idle: bool = False) -> None:
    """Raise the calling thread's nice value to ``nice`` (never lower it: that needs privileges), and
    with ``idle`` move it to Linux's ``SCHED_IDLE`` class.

    On Linux a nice value and a scheduling class belong to a thread, and the training runs on the Dask
    worker's one task thread, so that thread is what yields the CPU to the service's API and ingest;
    threads it starts later (torch's) inherit both. Elsewhere the nice value applies to the process
    and ``idle`` does nothing.

    Why the idle class as well: a niced thread still holds a core until the scheduler's next tick
    when a request arrives (its deadline is not yet due), while a thread of the idle class is
    preempted at once by any other thread that wakes, so a request waits on the training for
    microseconds rather than milliseconds. Unprivileged threads may enter the class, not leave it.
    """
    if nice > 0 and hasattr(os, "setpriority") and os.getpriority(os.PRIO_PROCESS, 0) < nice:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    if idle and hasattr(os, "SCHED_IDLE") and os.sched_getscheduler(0) != os.SCHED_IDLE:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))


def run_retrain(job: RetrainJob) -> RetrainResult:
    """Read the job's window from its store, learn the topology, return it (the Dask task body).

    Raises :class:`WindowGone` when the window no longer holds ``min_samples`` samples with encoder
    positions (retention pruned it, or the robot's clock went back to a new epoch long ago).

    The sensor networks start from the robot's newest stored weights trained under the job's
    baseline, on the same IMUs and joints (:mod:`service.store.weights`), when ``job.warm_start``;
    the weights trained come back in the result, for the service to store.
    """
    from bodyschema.impacts import drop_impacts
    from bodyschema.timing import lag_hinted
    from service.store import Store
    from service.store.weights import pack_weights

    lower_priority(job.nice, job.idle)
    wall0, cpu0 = time.monotonic(), time.process_time()
    store = Store(job.database_url)
    stored = None
    try:
        rec = store.read_window(job.robot, job.window_seconds, end=job.window_end, epoch=job.epoch)
        if rec is not None and job.warm_start and job.method in WARM_METHODS:
            stored = store.network_weights(
                job.robot, job.method, baseline_id=job.baseline_id, imus=rec.imu_names, joints=rec.joint_names
            )
    finally:
        store.close()
    if rec is None or rec.q is None or rec.n_samples < job.min_samples:
        raise WindowGone(
            f"window of {job.robot!r} ending at {job.window_end:g} (epoch {job.epoch}) holds too little data"
        )
    fits: list[TopologyFit] = []
    topo = lag_hinted(
        functools.partial(_fit, job, stored.weights if stored is not None else None, fits),
        drop_impacts(rec),
        job.lag_hint,
    )
    weights = fits[0].weights
    training = topo.training or {}
    converged = training.get("converged")
    return RetrainResult(
        key=job_key(job),
        robot=job.robot,
        method=job.method,
        window_end=job.window_end,
        topology=topo.to_json(),
        cpu_seconds=time.process_time() - cpu0,
        wall_seconds=time.monotonic() - wall0,
        epochs=training.get("epochs"),
        converged=None if converged is None else bool(converged),
        pid=os.getpid(),
        host=socket.gethostname(),
        weights=None if weights is None else pack_weights(weights),
        warm_from=stored.version if stored is not None and training.get("warm") else None,
        baseline_id=job.baseline_id,
        imus=tuple(rec.imu_names),
        joints=tuple(rec.joint_names),
    )


def _fit(job: RetrainJob, warm_start: Any, fits: list[TopologyFit], rec: Recording) -> Topology:
    """The job's estimate of ``rec``: the topology, and the fit (with the trained weights) in ``fits``."""
    from bodyschema.estimate import fit_topology

    kw: dict[str, Any] = {"warm_start": warm_start} if job.method in WARM_METHODS else {}
    kw["heldout_check"] = job.heldout_check
    fit = fit_topology(
        rec, method=job.method, timer=time.process_time, imu_delay=job.imu_delay, network=job.network, **kw
    )
    fits.append(fit)
    return fit.topology
