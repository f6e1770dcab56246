"""Pure machine output: while a ``--json`` command runs, file descriptor 1 belongs to the JSON alone.

Solvers write to the process's standard output from C: HiGHS prints its "Running HiGHS ..." banner
when a model is made, before any option can silence it. Python-level redirection (``sys.stdout``)
cannot catch that, so :func:`json_stdout` points descriptor 1 at standard error for the duration and
gives Python's ``sys.stdout`` a stream on the saved original: ``print`` reaches the caller's pipe, any
library's chatter reaches stderr.

Example (a C-level write and a print inside; only the print reaches stdout)::

    >>> import subprocess, sys
    >>> code = ("import os; from cli.machine_output import json_stdout\\n"
    ...         "with json_stdout():\\n    os.write(1, b'banner\\\\n'); print('{}')")
    >>> r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    >>> r.stdout, "banner" in r.stderr
    ('{}\\n', True)
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
from collections.abc import Iterator

__all__ = ["json_stdout"]


@contextlib.contextmanager
def json_stdout() -> Iterator[None]:
    """Send descriptor 1 to stderr; keep ``sys.stdout`` (Python prints) on the original stdout."""
    sys.stdout.flush()
    try:
        on_fd1 = sys.stdout.fileno() == 1
    except (AttributeError, OSError, ValueError):  # an in-memory stream (a caller capturing output)
        on_fd1 = False
    saved = os.dup(1)
    os.dup2(2, 1)
    original = sys.stdout
    real = io.TextIOWrapper(os.fdopen(saved, "wb", closefd=False), encoding="utf-8") if on_fd1 else None
    if real is not None:
        sys.stdout = real
    try:
        yield
    finally:
        if real is not None:
            real.flush()
            sys.stdout = original
        os.dup2(saved, 1)
        os.close(saved)
