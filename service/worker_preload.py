"""What every Dask worker process imports as it starts, before it takes a retrain.

A retrain's code imports torch, scikit-learn, SQLAlchemy and the estimators on first use: about 2.5 CPU
s that the first retrain in each worker process would otherwise pay, and that would count as that
retrain's cost and delay its robot. Dask runs a worker's *preload* modules while the worker starts,
before it joins the scheduler, so a worker that is up is ready to train at full speed:

* the embedded cluster names this module to its workers (:data:`service.cluster.WORKER_PRELOAD`);
* workers started by hand, or in compose, take ``--preload service.worker_preload``.

``dask_setup`` also sets torch to one thread per worker process
(:func:`bodyschema.threads.set_torch_threads`): each worker has one task thread, and the workers of a
machine share its cores.
"""

from __future__ import annotations

from typing import Any

# imported for their side effect: the modules (torch, scikit-learn, SQLAlchemy) are then loaded
import bodyschema.estimate
import bodyschema.health
import bodyschema.timing  # noqa: F401
import service.retrain.task
import service.store
import service.store.weights  # noqa: F401
from bodyschema.threads import set_torch_threads

__all__ = ["dask_setup"]


def dask_setup(worker: Any) -> None:
    """Called by Dask once the module is imported in a starting worker: one torch thread."""
    set_torch_threads()
