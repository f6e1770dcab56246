"""Benchmarks behind ``bodyhealth bench NAME``; results are written under ``docs/bench/``.

Each benchmark is a module here exposing ``add_arguments(parser)`` and ``run(args) -> Path`` (the
results file it wrote). :data:`BENCHMARKS` lists them in the order ``bench all`` runs them.
"""

from __future__ import annotations

import platform
from pathlib import Path

__all__ = ["BENCHMARKS", "RESULTS_DIR", "machine_note"]

BENCHMARKS: tuple[str, ...] = (
    "algebra",
    "sim",
    "topology",
    "scaling",
    "store",
    "ingest",
    "sim2real",
    "gravity",
    "realism",
    "docs",
)

#: Where results files and plots go (relative to the working directory: the repo root under make).
RESULTS_DIR = Path("docs/bench")


def machine_note() -> str:
    """One line naming the machine a result was measured on (benchmarks print it with every table)."""
    import os

    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            model = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), "")
    except OSError:
        model = platform.processor()
    return f"{os.cpu_count()} cores, {model or platform.machine()}, Python {platform.python_version()}"
