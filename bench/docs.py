"""Render the benchmark figures quoted in README.md and docs/*.md from the bench files (``--check``: compare).

A figure copied by hand from a results file goes stale the day the benchmark is run again, so every
figure the docs quote sits between markers and is rendered here from the file it comes from::

    <!-- fig:ID source=docs/bench/FILE -->
    ...text rendered from FILE, naming the machine and the command that produced it...
    <!-- /fig -->

``bodyhealth bench docs`` rewrites those blocks in place; ``--check`` changes nothing and exits 1
listing every block that differs from what its bench file says now (a test runs the same check). Where
a benchmark writes JSON the figures come from the JSON; where it writes only markdown (``algebra``,
``sim``, the transfer and timing columns of ``sim2real``) its table is parsed. Nothing is measured:
this reads ``docs/bench/`` only, so it is cheap and runs last in ``bench all``.
"""

from __future__ import annotations

import argparse
import re
import textwrap
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from bench import REPO_ROOT
from bench.figures import (
    alerts,
    algebra,
    calibration,
    drift,
    excitation,
    fleet,
    gravity,
    import_,
    ingest,
    kinematics,
    lever_budget,
    load,
    machines,
    realism,
    robots,
    rotations,
    scaling,
    shapes,
    sim,
    sim2real,
    store,
    topology,
    writes,
)
from bench.figures.files import BENCH, BenchFiles

__all__ = [
    "BENCH",
    "FIGURES",
    "Block",
    "Figure",
    "add_arguments",
    "blocks",
    "check",
    "render",
    "run",
    "update",
]

_MARK = re.compile(
    r"<!-- fig:(?P<id>[A-Za-z0-9_.-]+) source=(?P<source>\S+) -->(?P<body>.*?)<!-- /fig -->", re.S
)


@dataclass(frozen=True)
class Figure:
    """One marked block: which doc, which marker id, which bench file it is rendered from, and how."""

    doc: str
    id: str
    source: str
    render: Callable[[BenchFiles], str]


def _f(doc: str, id_: str, source: str, render: Callable[[BenchFiles], str]) -> Figure:
    return Figure(doc, id_, f"{BENCH}/{source}" if source else BENCH, render)


#: Every figure block in the docs. A block in a doc that is not listed here, or listed and missing
#: from its doc, fails the check as much as a stale one.
FIGURES: tuple[Figure, ...] = (
    _f("README.md", "bench-machines", "", machines.figure),
    _f("README.md", "algebra", "algebra.md", algebra.readme),
    _f("README.md", "topology", "topology.json", topology.readme),
    _f("README.md", "scaling", "scaling.json", scaling.readme),
    _f("README.md", "network-cost", "topology.json", topology.network_cost),
    _f("README.md", "sim", "sim.md", sim.readme),
    _f("README.md", "store", "store.json", store.readme),
    _f("README.md", "ingest", "ingest.json", ingest.readme),
    _f("README.md", "load", "load.json", load.readme),
    _f("README.md", "sim2real", "sim2real", sim2real.readme),
    _f("README.md", "gravity", "gravity.json", gravity.readme),
    _f("docs/algebra.md", "algebra", "algebra.md", algebra.doc),
    _f("docs/topology.md", "fast-shortest", "topology.json", topology.fast_shortest),
    _f("docs/topology.md", "network-paper", "topology.json", topology.network_paper),
    _f("docs/topology.md", "scaling", "scaling.json", scaling.doc),
    _f("docs/topology.md", "topology", "topology.json", topology.doc),
    _f("docs/simulators.md", "sim", "sim.md", sim.doc),
    _f("docs/store.md", "store", "store.json", store.doc),
    _f("docs/store.md", "writes", "writes.json", writes.doc),
    _f("docs/transports.md", "ingest", "ingest.json", ingest.doc),
    _f("docs/sim2real.md", "example", "sim2real/02_undisturbed_slow_rotation_B/report.md", sim2real.example),
    _f("docs/sim2real.md", "results", "sim2real", sim2real.doc),
    _f("docs/sim2real.md", "detect", "sim2real-detect.json", sim2real.detect),
    _f("docs/sim2real.md", "encoders", "sim2real-encoders.json", sim2real.encoders),
    _f("docs/sim2real.md", "gravity", "gravity.json", gravity.doc),
    _f("docs/sim2real.md", "gravity-networks", "gravity.json", gravity.networks),
    # the realism figures, the robot preset's and the on-chip filter's, on both pages
    *(
        _f(page, name, f"{stem}.json", partial(realism.figure, name=stem))
        for page in ("docs/topology.md", "README.md")
        for name, stem in (("realism", "realism"), ("realism-onchip-filter", "realism-onchip-filter/realism"))
    ),
    _f("docs/topology.md", "shapes", "shapes.json", shapes.figure),
    _f("docs/kinematics.md", "shapes-axis-floor", "shapes.json", shapes.axis_floor),
    _f("docs/robots.md", "robots", "robots.json", robots.figure),
    _f("docs/robots.md", "robots-foot-plane", "robots.json", robots.foot_plane),
    # the full bench, the run beside other work, the hour-long run with its restart on its own
    *(
        _f("docs/alert-latency.md", name, f"{name}.json", partial(alerts.figure, name=name))
        for name in (
            "alerts",
            "alerts-first",
            "alerts-loaded",
            "alerts-restart",
            "alerts-approvals",
            "alerts-approvals5",
            "alerts-store-lock",
            "alerts-passive-checkpoint",
            "alerts-switch-interval",
            "alerts-switch-5ms",
            "alerts-damages-1ms",
            "alerts-1ms",
        )
    ),
    _f("docs/excitation.md", "excitation", "excitation.json", excitation.figure),
    _f("docs/topology.md", "calibration", "calibration.json", calibration.figure),
    _f("docs/recording-format.md", "import", "import.json", import_.doc),
    _f("docs/kinematics.md", "kinematics", "kinematics.json", kinematics.figure),
    _f("README.md", "kinematics", "kinematics.json", kinematics.figure),
    _f("docs/kinematics.md", "drift", "drift.json", drift.figure),
    _f(
        "docs/kinematics.md",
        "drift-accelerometer-frame",
        "drift-accelerometer-frame/drift.json",
        lambda b: drift.figure(b, "drift-accelerometer-frame/drift"),
    ),
    _f("docs/kinematics.md", "lever-budget", "lever-budget.json", lever_budget.figure),
    _f("docs/kinematics.md", "rotations", "rotations.json", rotations.figure),
    _f("docs/scale.md", "fleet", "fleet.json", fleet.doc),
)


# ---------------------------------------------------------------------------------------------------
# Reading and writing the docs


@dataclass(frozen=True)
class Block:
    """A marked block as it stands in a doc."""

    doc: str
    id: str
    source: str
    body: str


def blocks(root: Path | str = ".", docs: Iterable[str] | None = None) -> list[Block]:
    """Every marked block in README.md and docs/*.md (or in ``docs``), in file order."""
    root = Path(root)
    names = list(docs) if docs is not None else _doc_names(root)
    out = []
    for name in names:
        text = (root / name).read_text(encoding="utf-8")
        out += [Block(name, m["id"], m["source"], m["body"]) for m in _MARK.finditer(text)]
    return out


def _doc_names(root: Path) -> list[str]:
    return ["README.md", *(f"docs/{p.name}" for p in sorted((root / "docs").glob("*.md")))]


#: Width prose lines in a rendered block are wrapped to, as the docs are.
WRAP = 105


def _wrap(text: str) -> str:
    """Wrap prose and bullets to :data:`WRAP`; tables, code blocks and blank lines stay as they are."""
    out, code = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            code = not code
        if code or line.startswith(("```", "|")) or not line.strip():
            out.append(line)
            continue
        bullet = line.startswith("* ")
        out.append(
            textwrap.fill(
                line,
                WRAP,
                subsequent_indent="  " if bullet else "",
                break_long_words=False,
                break_on_hyphens=False,
            )
        )
    return "\n".join(out)


def _body(text: str) -> str:
    return f"\n{_wrap(text.strip())}\n"


def render(root: Path | str = ".") -> dict[tuple[str, str], str]:
    """What every block in :data:`FIGURES` should hold, rendered from the bench files under ``root``."""
    b = BenchFiles(Path(root))
    return {(f.doc, f.id): _body(f.render(b)) for f in FIGURES}


def _render_each(root: Path) -> tuple[dict[tuple[str, str], str], list[str]]:
    """Like :func:`render`, but a bench file that cannot be read becomes a problem line, not a crash."""
    b = BenchFiles(root)
    out, problems = {}, []
    for f in FIGURES:
        try:
            out[(f.doc, f.id)] = _body(f.render(b))
        except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError) as err:
            problems.append(f"{f.doc}: fig:{f.id} cannot be rendered from {f.source}: {err!r}")
    return out, problems


def check(root: Path | str = ".") -> list[str]:
    """One line per problem: a stale block, a missing or unknown one, a block naming the wrong source."""
    root = Path(root)
    want, problems = _render_each(root)
    sources = {(f.doc, f.id): f.source for f in FIGURES}
    broken = {(f.doc, f.id) for f in FIGURES} - want.keys()
    seen: set[tuple[str, str]] = set()
    for blk in blocks(root):
        key = (blk.doc, blk.id)
        if key in seen:
            problems.append(f"{blk.doc}: fig:{blk.id} appears twice")
        seen.add(key)
        if key in broken:
            continue
        if key not in want:
            problems.append(f"{blk.doc}: fig:{blk.id} is not a known figure (service/bench/docs.py FIGURES)")
        elif blk.source != sources[key]:
            problems.append(f"{blk.doc}: fig:{blk.id} says source={blk.source}, it comes from {sources[key]}")
        elif blk.body != want[key]:
            problems.append(
                f"{blk.doc}: fig:{blk.id} differs from {sources[key]}:\n{_diff(blk.body, want[key])}"
            )
    for key in sorted(want.keys() - seen):
        problems.append(f"{key[0]}: fig:{key[1]} is missing (source {sources[key]})")
    return problems


def _diff(have: str, want: str) -> str:
    import difflib

    lines = difflib.unified_diff(
        have.splitlines(), want.splitlines(), "in the doc", "from the bench", lineterm="", n=0
    )
    return "\n".join("    " + ln for ln in lines)


def update(root: Path | str = ".") -> list[str]:
    """Rewrite every known block in place; returns the docs that changed."""
    root = Path(root)
    want = render(root)
    changed = []
    for name in sorted({doc for doc, _ in want}):
        path = root / name
        text = path.read_text(encoding="utf-8")

        def sub(m: re.Match[str], name: str = name) -> str:
            key = (name, m["id"])
            if key not in want:
                return m.group(0)
            source = next(f.source for f in FIGURES if (f.doc, f.id) == key)
            return f"<!-- fig:{m['id']} source={source} -->{want[key]}<!-- /fig -->"

        new = _MARK.sub(sub, text)
        if new != text:
            path.write_text(new, encoding="utf-8")
            changed.append(name)
    return changed


# ---------------------------------------------------------------------------------------------------
# CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--check",
        action="store_true",
        help="change nothing; exit 1 listing every figure block that differs from its bench file",
    )
    parser.add_argument(
        "--root", type=Path, default=REPO_ROOT, help="repository root (default: the one this package is in)"
    )


def run(args: argparse.Namespace) -> Path:
    """Rewrite the figure blocks (or, with ``--check``, report the stale ones and exit 1)."""
    root = Path(args.root)
    if args.check:
        problems = check(root)
        if problems:
            print("\n".join(problems))
            print(f"{len(problems)} figure block(s) out of date; `make docs` rewrites them")
            raise SystemExit(1)
        print(f"{len(FIGURES)} figure blocks match their bench files")
        raise SystemExit(0)
    missing = [
        f"{doc}: fig:{id_}" for doc, id_ in render(root).keys() - {(b.doc, b.id) for b in blocks(root)}
    ]
    changed = update(root)
    for name in changed:
        print(f"rewrote figures in {name}")
    if not changed:
        print("every figure block already matches its bench file")
    if missing:
        print("no marker yet (add `<!-- fig:ID source=... --><!-- /fig -->` where it belongs):")
        print("\n".join("  " + m for m in sorted(missing)))
    return root / (changed[0] if changed else "README.md")
