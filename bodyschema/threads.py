"""The one place that sets how many CPU threads the numerical libraries use.

Two pools matter here: torch's intra-op threads (the sensor networks) and the BLAS behind numpy and
scipy (the least-squares fits). Both default to every core, which on the small machines this runs on
(and inside a worker process that shares them) mostly buys spin-waiting: a training step or a fit
here is a few small products. Whoever wants another count asks here, so the policy lives in one module.

>>> with blas_threads(1):
...     pass
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

__all__ = ["TORCH_THREADS_ENV", "blas_threads", "set_blas_threads", "set_torch_threads"]

#: Environment variable that overrides the torch thread count (default 1).
TORCH_THREADS_ENV = "BODYHEALTH_TORCH_THREADS"


def set_torch_threads(limit: int | None = None) -> int:
    """Use ``limit`` CPU threads in torch (default: ``BODYHEALTH_TORCH_THREADS`` or 1); returns it.

    One thread by default: a training step here is a few small batched products, and a second
    OpenMP thread mostly spin-waits — measured 7x more CPU time per step on a shared 2-core machine.
    """
    import torch

    n = limit or int(os.environ.get(TORCH_THREADS_ENV, "1"))
    n = max(1, min(n, os.cpu_count() or 1))
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n


@contextlib.contextmanager
def blas_threads(limit: int = 1) -> Iterator[None]:
    """BLAS limited to ``limit`` threads inside the block (threadpoolctl; restored after): the fits
    here are tall and thin (samples x a few dozen columns), where threads only add synchronisation."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=limit, user_api="blas"):
        yield


def set_blas_threads(limit: int = 1) -> None:
    """BLAS limited to ``limit`` threads for the rest of this process: for a child that only fits.

    threadpoolctl limits the BLAS libraries loaded when it is called, so numpy's and scipy's (scipy
    wheels bring their own OpenBLAS) are loaded first. Measured on a 2-core machine beside other work:
    a UR5e window's geometry in the accelerometers' frame took 6.5 CPU s and 5 s of wall time with
    BLAS on every core, 1.7 s of both on one thread.
    """
    import numpy  # noqa: F401  (loads numpy's BLAS)
    import scipy.linalg  # noqa: F401  (loads scipy's)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=limit, user_api="blas")  # not as a context: nothing restores it
