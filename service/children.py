"""Child processes of the service: how they start and how they end with it.

The service starts children for CPU-bound work that must not hold its interpreter lock (the worker's
estimates, :mod:`service.estimation`; the simulated farm, :class:`service.ingest.farm.FarmProcess`).
They are forks of a **fork server**: a process spawned clean (the service has threads by then, which a
fork of the service itself would copy half-way) that imports once what the children run
(:data:`PRELOAD`). A child then starts in 0.05 s instead of importing numpy, SciPy and MuJoCo anew,
1.5 s each time on an idle machine and more on a loaded one; the children also share those modules'
pages. A SIGKILL of the service tells a child nothing (it is reparented and keeps running), so each
child watches the service itself and ends as soon as it has gone. Not its parent: the fork server
lives as long as any process that may still ask it for a child, the children included, so it would
never end first.
"""

from __future__ import annotations

import multiprocessing
import os
import select
import threading
import time
from multiprocessing.context import ForkServerContext

__all__ = ["CHILDREN", "PRELOAD", "exit_with_service"]

#: What the children run, imported by the fork server before it forks the first: the estimates
#: (the fast method, the geometry, the health checks) and the farm. Not PyTorch (1.6 CPU s): the
#: estimator's child trains the sensor networks only in a service without a training cluster, and
#: imports it then.
PRELOAD = (
    "bodyschema.estimate",
    "bodyschema.kinematics",
    "bodyschema.health",
    "bodyschema.impacts",
    "simulators.farm",
)

#: The start method of every child of the service (module doc).
CHILDREN: ForkServerContext = multiprocessing.get_context("forkserver")
CHILDREN.set_forkserver_preload(list(PRELOAD))


def exit_with_service(service: int, poll: float = 1.0) -> None:
    """In a child: end the process (``os._exit(0)``) once ``service`` has ended, at once if it already
    has (it may have died while the child started).

    A pidfd wakes the watching thread the moment the service ends, a zombie not yet reaped included;
    where the kernel has none (Linux before 5.3), the thread asks every ``poll`` s instead.
    """
    try:
        fd = os.pidfd_open(service)
    except ProcessLookupError:
        os._exit(0)
    except (AttributeError, OSError):
        fd = None

    def watch() -> None:
        if fd is not None:
            select.select([fd], [], [])
        else:
            while _alive(service):
                time.sleep(poll)
        os._exit(0)

    threading.Thread(target=watch, name="exit-with-service", daemon=True).start()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True
