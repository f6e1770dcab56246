"""A Dask worker preload: the embedded cluster's worker processes log as the service does.

A worker process is a fresh interpreter; ``import distributed`` gives it distributed's own text
handler, so its warnings (a retrain cancelled at shutdown) came out as plain lines among the service's
JSON ones. The embedded cluster (:func:`service.cluster.local_cluster`) names this module as a preload
and passes the service's format in :data:`service.log_config.CHILD_LOG_ENV`; a worker started by hand
without it keeps distributed's format.
"""

from __future__ import annotations

from typing import Any

from service.log_config import configure_child_logging

__all__ = ["dask_setup"]


def dask_setup(worker: Any) -> None:
    """Called by Dask in a starting worker process: take the service's log format."""
    configure_child_logging()
