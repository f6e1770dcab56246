"""Benchmarks behind ``bodyhealth bench NAME``; results are written under the repository's ``docs/bench/``.

Each benchmark is a module here exposing ``add_arguments(parser)`` and ``run(args) -> Path`` (the
results file it wrote); every one takes ``--out`` (an explicit results folder) whose default,
:data:`RESULTS_DIR`, is found from this package, not from the working directory, so a benchmark run
from anywhere updates the figures the docs cite. :data:`BENCHMARKS` lists them in the order
``bench all`` runs them; a trailing ``_`` keeps a name that is a Python keyword importable
(``import_`` is ``bodyhealth bench import``).
"""

from __future__ import annotations

import platform
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from concurrent.futures import ProcessPoolExecutor

__all__ = [
    "BENCHMARKS",
    "REPO_ROOT",
    "RESULTS_DIR",
    "detection_table",
    "fmt",
    "machine_note",
    "map_jobs",
    "process_pool",
    "write_results",
]

BENCHMARKS: tuple[str, ...] = (
    "algebra",
    "sim",
    "topology",
    "scaling",
    "store",
    "writes",
    "load",
    "ingest",
    "sim2real",
    "sim2real_detect",
    "sim2real_encoders",
    "gravity",
    "realism",
    "calibration",
    "shapes",
    "warmstart",
    "fleet",
    "import_",
    "kinematics",
    "rotations",
    "drift",
    "lever_budget",
    "alerts",
    "excitation",
    "robots",
    "docs",
)

#: The repository this package was installed from (editable install: ``pip install -e .``).
REPO_ROOT = Path(__file__).resolve().parents[1]

#: Where results files and plots go by default: the repository's docs/bench.
RESULTS_DIR = REPO_ROOT / "docs" / "bench"


def machine_note(cpuinfo: str = "/proc/cpuinfo") -> str:
    """One line naming the machine a result was measured on (benchmarks print it with every table).

    The CPU's family and model numbers follow its name: a hypervisor often shows only "AMD EPYC" for
    CPUs of different speeds, so the name alone does not say which figures can be set side by side.
    """
    import os

    fields: dict[str, str] = {}
    try:
        with open(cpuinfo, encoding="utf-8") as fh:
            for ln in fh:
                if not ln.strip():
                    break  # the first processor's block names them all
                key, _, value = ln.partition(":")
                fields.setdefault(key.strip(), value.strip())
    except OSError:
        fields = {"model name": platform.processor()}
    name = fields.get("model name") or platform.machine()
    if fields.get("cpu family") and fields.get("model"):
        name += f" (family {fields['cpu family']}, model {fields['model']})"
    return f"{os.cpu_count()} cores, {name}, Python {platform.python_version()}"


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes for a bench's runs: forks of the service's fork server
    (:mod:`service.children`), never of the bench itself, which may hold threads, MuJoCo state or
    PyTorch's thread pools that a fork would copy half set up."""
    from concurrent.futures import ProcessPoolExecutor

    from service.children import CHILDREN

    return ProcessPoolExecutor(max_workers=workers, mp_context=CHILDREN)


def map_jobs(
    fn: Callable[..., Any],
    jobs: Sequence[tuple],
    workers: int,
    desc: str,
    unit: str,
    on_result: Callable[[Any], None] | None = None,
) -> list[Any]:
    """``[fn(*job) for job in jobs]`` in order, on ``workers`` processes (:func:`process_pool`) when
    more than one, with a progress bar. ``on_result`` sees each result as it arrives, so a long bench
    can save what it has done."""
    from bodyschema.progress import progress

    out: list[Any] = []
    bar = progress(total=len(jobs), desc=desc, unit=unit)
    if workers > 1 and len(jobs) > 1:
        with process_pool(workers) as pool:
            for res in pool.map(fn, *zip(*jobs, strict=True)):
                out.append(res)
                if on_result is not None:
                    on_result(res)
                bar.update(1)
    else:
        for job in jobs:
            out.append(fn(*job))
            if on_result is not None:
                on_result(out[-1])
            bar.update(1)
    bar.close()
    return out


def fmt(x: float | None, spec: str = ".2f", unit: str = "") -> str:
    """A table cell: ``x`` formatted by ``spec`` and followed by ``unit``, or a dash where there is none.

    >>> fmt(1.234), fmt(None), fmt(0.5, ".0%"), fmt(2.5, "g", " ms"), fmt(None, "g", " ms")
    ('1.23', '—', '50%', '2.5 ms', '—')
    """
    return "—" if x is None else format(x, spec) + unit


def write_results(
    out: Path | str, stem: str, data: dict, markdown: str, plot: Callable[[Path], None]
) -> Path:
    """Write a bench's ``STEM.json`` (``data``), ``STEM.png`` (``plot(path)``) and ``STEM.md``
    (``markdown``) under ``out``, creating it; returns the markdown's path, the file the docs cite."""
    import json

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.json").write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    plot(out / f"{stem}.png")
    path = out / f"{stem}.md"
    path.write_text(markdown, encoding="utf-8")
    return path


def detection_table(
    rows: Sequence[tuple[str, Sequence[float], Sequence[dict]]], factors: Sequence[float], over: str
) -> list[str]:
    """The hidden-effect benches' table: per effect, the range of its detection limits (``over`` what)
    and, per factor, how many of the effects hidden alone were named and how many within 3 sigma.

    ``rows``: (effect, its limits, one ``{"n", "named", "within"}`` count per factor).

    >>> row = ("gyro_bias", [0.002, 0.004], [{"n": 2, "named": 2, "within": 1}])
    >>> detection_table([row], [3.0], "trials")[2]
    '| gyro_bias | 0.002–0.004 | 2/2 | 1/2 |'
    """
    lines = [
        f"| effect | detection limit (range over {over}) | "
        + " | ".join([f"named at {x:g}x" for x in factors] + [f"within 3σ at {x:g}x" for x in factors])
        + " |",
        "|---|---|" + "---|" * (2 * len(factors)),
    ]
    for effect, limits, counts in rows:
        span = f"{min(limits):.3g}–{max(limits):.3g}" if len(limits) else "–"
        named = [f"{c['named']}/{c['n']}" for c in counts]
        cells = [span, *named, *(f"{c['within']}/{c['n']}" for c in counts)]
        lines.append(f"| {effect} | " + " | ".join(cells) + " |")
    return lines
