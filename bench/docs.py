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
import json
import re
import statistics
import textwrap
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from bench import REPO_ROOT, fmt

__all__ = [
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

#: Where the bench files live, relative to the repository root.
BENCH = "docs/bench"

#: Targets the docs measure against. They are requirements, not results, so no bench file holds them.
INGEST_TARGET_X = 10.0
TOPOLOGY_FAST_TARGET_S = ("humanoid", 2.0)
TOPOLOGY_NETWORK_TARGET_S = ("ur5e", 60.0)

_MARK = re.compile(
    r"<!-- fig:(?P<id>[A-Za-z0-9_.-]+) source=(?P<source>\S+) -->(?P<body>.*?)<!-- /fig -->", re.S
)
_MACHINE = re.compile(r"(?:Machine|Measured on): (.+?Python \d+(?:\.\d+)*)")
_COMMAND = re.compile(r"`(bodyhealth bench [^`]+)`")
_LOAD = re.compile(r"[Ll]oad average[^0-9]{0,40}([0-9]+(?:\.[0-9]+)?)")


# ---------------------------------------------------------------------------------------------------
# Reading the bench files


class _Bench:
    """The bench files under one repository root, read once per render."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    @cache  # noqa: B019 - one instance per render; the cache dies with it
    def text(self, rel: str) -> str:
        return (self.root / BENCH / rel).read_text(encoding="utf-8")

    @cache  # noqa: B019
    def json(self, rel: str) -> object:
        return json.loads(self.text(rel))

    def machine(self, name: str) -> str:
        """The machine line the bench wrote: from its JSON when that has one, else from its markdown."""
        path = self.root / BENCH / f"{name}.json"
        if path.exists():
            data = self.json(f"{name}.json")
            runs = data if isinstance(data, list) else [data]
            found = list(dict.fromkeys(r["machine"] for r in runs if isinstance(r, dict) and "machine" in r))
            if found:
                return "; ".join(found)
        m = _MACHINE.search(self.text(f"{name}.md"))
        if m is None:
            raise ValueError(f"{BENCH}/{name}.md names no machine")
        return m.group(1)

    def command(self, name: str) -> str:
        """The command line the bench file quotes, or the bench with its defaults when it quotes none."""
        m = _COMMAND.search(self.text(f"{name}.md"))
        return m.group(1) if m else f"bodyhealth bench {name}"

    def load(self, name: str) -> str | None:
        m = _LOAD.search(self.text(f"{name}.md"))
        return m.group(1) if m else None

    def provenance(self, name: str) -> str:
        """'`COMMAND` on MACHINE': what every rendered block says about where its figures come from."""
        return f"`{self.command(name)}` on {self.machine(name)}"

    def table(self, rel: str, first_header: str, nth: int = 0) -> list[dict[str, str]]:
        """The ``nth`` markdown table in ``rel`` whose first header cell is ``first_header``."""
        return _md_tables(self.text(rel), first_header)[nth]


def _md_tables(text: str, first_header: str) -> list[list[dict[str, str]]]:
    tables: list[list[dict[str, str]]] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        cells = _cells(lines[i])
        if cells and cells[0] == first_header and i + 1 < len(lines) and lines[i + 1].startswith("|--"):
            rows, i = [], i + 2
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(dict(zip(cells, _cells(lines[i]), strict=True)))
                i += 1
            tables.append(rows)
        i += 1
    if not tables:
        raise ValueError(f"no table starting with {first_header!r}")
    return tables


def _cells(line: str) -> list[str]:
    line = line.strip()
    if not line.startswith("|"):
        return []
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip("|"))]


def _num(cell: str) -> float:
    """The first number in a table cell ('38,723', '30.6× (meets 20×)', '0.152 (0.120-0.184)')."""
    m = re.search(r"-?[0-9][0-9,]*(?:\.[0-9]+)?", cell)
    if m is None:
        raise ValueError(f"no number in {cell!r}")
    return float(m.group(0).replace(",", ""))


# ---------------------------------------------------------------------------------------------------
# Formatting


def _span(values: Iterable[float], fmt: str = ".2f") -> str:
    """'lo–hi', or one value when both print alike."""
    vals = list(values)
    lo, hi = f"{min(vals):{fmt}}", f"{max(vals):{fmt}}"
    return lo if lo == hi else f"{lo}–{hi}"


def _int(x: float) -> str:
    return f"{round(x):,}"


def _row(cells: Iterable[object]) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


# ---------------------------------------------------------------------------------------------------
# The figures


def _machines(b: _Bench) -> str:
    names = [p.stem for p in sorted((b.root / BENCH).glob("*.md")) if p.stem != "README"]
    lines = [
        "| bench | machine | command | load average when it ran |",
        "|---|---|---|---:|",
    ]
    for name in names:
        lines.append(_row([f"`{name}`", b.machine(name), f"`{b.command(name)}`", b.load(name) or "—"]))
    return "\n".join(lines)


def _algebra(b: _Bench) -> str:
    rows = b.table("algebra.md", "N")
    text = b.text("algebra.md")
    m = re.search(r"(\d+)% of the N x N matrix bits flipped, median of (\d+)", text)
    target = re.search(r"Target N = (\d+) under ([0-9.]+) s: (\w+) \(median ([0-9.]+) s\)", text)
    if m is None or target is None:
        raise ValueError("algebra.md: settings or target line not found")
    lines = [
        f"Measured with {b.provenance('algebra')}: random out-trees with {m.group(1)} % of the N×N matrix "
        f"bits flipped, median of {m.group(2)}. Target: N = {target.group(1)} under {target.group(2)} s — "
        f"{target.group(3)} ({target.group(4)} s).",
        "",
        "| N | flipped bits | `correct` median s | distance found (truth at flipped) "
        "| trellis (Alg. 3) alone: s / distance |",
        "|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        lines.append(
            _row(
                [
                    r["N"],
                    r["flipped bits"],
                    f"{_num(r['correct: median s (min-max)']):.3f}",
                    r["distance"],
                    f"{r['trellis (Alg. 3) alone: s']} / {r['trellis distance']}",
                ]
            )
        )
    return "\n".join(lines)


def _algebra_doc(b: _Bench) -> str:
    rows = b.table("algebra.md", "N")
    sparse = b.table("algebra.md", "N", 1)
    m = re.search(r"(\d+)% of the N x N matrix bits flipped, median of (\d+)", b.text("algebra.md"))
    assert m is not None
    sizes = ", ".join(r["N"] for r in rows)
    worst = max(rows, key=lambda r: int(r["N"]))
    return (
        f"In the run recorded there ({b.provenance('algebra')}), N = {sizes} with {m.group(1)} % of the "
        f"bits flipped (median of {m.group(2)}): `correct` takes "
        f"{_span([_num(r['correct: median s (min-max)']) for r in rows], '.3f')} s and ends at "
        f"distance {worst['distance']} for N = {worst['N']} ({worst['flipped bits']} bits flipped), "
        f"where the trellis alone stops at {worst['trellis distance']}; with N//4 bits flipped the "
        f"exact stage certified {_span([_num(r['certified']) for r in sparse], '.0f')} of "
        f"{_span([_num(r['certified'].split('/')[1]) for r in sparse], '.0f')} trees per N."
    )


def _topology_rows(b: _Bench) -> list[dict]:
    return b.json("topology.json")  # type: ignore[return-value]


def _topology_settings(b: _Bench) -> dict[str, str]:
    return dict(re.findall(r"--([\w-]+) (\S+)", b.command("topology")))


def _topology_setup(b: _Bench) -> str:
    rows = {r["robot"]: r for r in _topology_rows(b)}
    s = _topology_settings(b)
    hz = re.search(r"(\d+) s at\s+(\d+) Hz", b.text("topology.md"))
    rate = hz.group(2) if hz else "100"
    preset = re.search(r"`([\w-]+)` IMU preset", b.text("topology.md"))
    if preset is None:
        raise ValueError("topology.md: IMU preset not found")
    frobot, ftarget = TOPOLOGY_FAST_TARGET_S
    nrobot, ntarget = TOPOLOGY_NETWORK_TARGET_S
    fast_s, net_s = rows[frobot]["fast"]["seconds"], rows[nrobot]["network"]["seconds"]
    return (
        f"Measured with {b.provenance('topology')}: every catalog robot, `{preset.group(1)}` IMU model "
        f"(bias, scale, cross-axis, noise), {s['seconds']} s at {rate} Hz, {s['seeds']} seeds, {s['epochs']} "
        f"training epochs, one uninterrupted run. *Exact* = every joint's parent and every IMU's joint "
        "equal the truth. CPU seconds are medians per run; the network and MLP costs are ratios to "
        f"`fast` on the same recordings in the same run. Targets: `fast` ≤ {ftarget:g} s for the "
        f"{frobot} ({'met' if fast_s <= ftarget else 'missed'}: {fast_s:.2f} s), `network` ≤ "
        f"{ntarget:g} s for `{nrobot}` ({'met' if net_s <= ntarget else 'missed'}: {net_s:.0f} s)."
    )


def _exact(m: dict) -> str:
    return f"{m['exact']}/{m['runs']}"


def _ratio(r: dict, method: str) -> float:
    return r[method]["seconds"] / r["fast"]["seconds"]


def _topology_readme(b: _Bench) -> str:
    lines = [
        "| robot | joints | IMUs | `fast` exact | `network` exact | `network-paper` | `mlp` "
        "| shortest exact `fast` | `fast` CPU s | network CPU ×fast | mlp CPU ×fast |",
        "|---|---:|---:|---|---|---|---|---:|---:|---:|---:|",
    ]
    for r in _topology_rows(b):
        lines.append(
            _row(
                [
                    r["robot"],
                    r["joints"],
                    r["imus"],
                    _exact(r["fast"]),
                    _exact(r["network"]),
                    _exact(r["network-paper"]),
                    _exact(r["mlp"]),
                    f"{r['shortest']:g} s",
                    f"{r['fast']['seconds']:.2f}",
                    f"{_ratio(r, 'network'):.0f}× ({r['network']['seconds']:.0f} s)",
                    f"{_ratio(r, 'mlp'):.0f}×",
                ]
            )
        )
    return "\n".join(lines)


def _totals(rows: list[dict], method: str) -> str:
    return f"{sum(r[method]['exact'] for r in rows)}/{sum(r[method]['runs'] for r in rows)}"


def _weakest(rows: list[dict]) -> dict:
    return min(rows, key=lambda r: r["network"]["true_min"] - r["network"]["false_max"])


def _topology_margins(b: _Bench) -> str:
    rows = _topology_rows(b)
    weak = _weakest(rows)
    others = [r for r in rows if r is not weak]
    wrong = weak["network"]["wrong"]
    seeds = [str(i) for i, w in enumerate(wrong) if w]
    repaired = (
        f" (seed {', '.join(seeds)}, where the correction repairs the {sum(wrong)} wrong entries)"
        if seeds
        else ""
    )
    paper = [r["network-paper"]["true_min"] for r in rows]
    fast, net = _totals(rows, "fast"), _totals(rows, "network")
    exact = (
        f"`fast` and `network` are exact in {fast} runs each."
        if fast == net
        else f"`fast` is exact in {fast} runs, `network` in {net}."
    )
    return (
        f"{exact} The weakest margin is the {weak['robot']}'s: its smallest true dependency feature is "
        f"{weak['network']['true_min']:.3f} against a largest false one of "
        f"{weak['network']['false_max']:.3f}{repaired}; on every other robot true features are ≥ "
        f"{min(r['network']['true_min'] for r in others):.2f} and false ones ≤ "
        f"{max(r['network']['false_max'] for r in others):.2f}. The paper's variance statistic "
        f"(`network-paper`) scores {_totals(rows, 'network-paper')}, with a smallest true feature of "
        f"0.000 on {sum(f'{x:.3f}' == '0.000' for x in paper)} of {len(rows)} robots and at most "
        f"{max(paper):.3f} on the others."
    )


def _topology_readme_all(b: _Bench) -> str:
    return "\n\n".join([_topology_setup(b), _topology_readme(b), _topology_margins(b)])


def _scaling_series(b: _Bench) -> dict[str, list[dict]]:
    return b.json("scaling.json")["series"]  # type: ignore[index]


def _slope(rows: list[dict], key: str) -> float:
    x = np.log([r[key] for r in rows])
    y = np.log([r["cpu_s"] for r in rows])
    return float(np.polyfit(x, y, 1)[0])


def _scaling_readme(b: _Bench) -> str:
    s = _scaling_series(b)
    j, i, t = s["joints"], s["imus"], s["samples"]
    secs = j[0]["samples"] / 100
    return (
        f"Measured with {b.provenance('scaling')}, `fast` on one CPU thread: joints {j[0]['joints']} → "
        f"{j[-1]['joints']}: {j[0]['cpu_s']:.3f} → {j[-1]['cpu_s']:.3f} s at {secs:g} s of data "
        f"(log-log slope {_slope(j, 'joints'):.2f}); IMUs {i[0]['imus']} → {i[-1]['imus']} on "
        f"{i[0]['joints']} joints: {i[0]['cpu_s']:.3f} → {i[-1]['cpu_s']:.3f} s (slope "
        f"{_slope(i, 'imus'):.2f}); samples {t[0]['samples']:,} → {t[-1]['samples']:,}: "
        f"{t[0]['cpu_s']:.3f} → {t[-1]['cpu_s']:.3f} s (slope {_slope(t, 'samples'):.2f})."
    )


def _scaling_doc(b: _Bench) -> str:
    s = _scaling_series(b)
    exact = all(p["exact"] for rows in s.values() for p in rows)
    heads = {
        "joints": f"joints N (1 IMU/link, {s['joints'][0]['samples'] / 100:g} s)",
        "imus": f"IMUs K ({s['imus'][0]['joints']} joints, {s['imus'][0]['samples'] / 100:g} s)",
        "samples": f"samples T ({s['samples'][0]['joints']} joints)",
    }
    lines = [
        f"Measured with {b.provenance('scaling')}; exact on {'every' if exact else 'not every'} point:",
    ]
    for key, head in heads.items():
        rows = s[key]
        lines += [
            "",
            _row([head, *(f"{r[key]:,}" for r in rows)]),
            "|---" * (len(rows) + 1) + "|",
            _row(["CPU s", *(f"{r['cpu_s']:.3f}" for r in rows)]),
        ]
    lines += [
        "",
        f"Log-log slopes: {_slope(s['joints'], 'joints'):.2f} in joints, {_slope(s['imus'], 'imus'):.2f} "
        f"in IMUs, {_slope(s['samples'], 'samples'):.2f} in samples.",
    ]
    return "\n".join(lines)


def _network_cost(b: _Bench) -> str:
    rows = _topology_rows(b)
    s = _topology_settings(b)
    big = [r for r in rows if r["robot"].startswith("paper-") or r["robot"] == "humanoid"]
    ur = next(r for r in rows if r["robot"] == "ur5e")
    return (
        f"About {_span([r['network']['seconds'] / r['imus'] for r in big], '.1f')} CPU s per IMU per "
        f"{s['seconds']} s recording at {s['epochs']} epochs on the paper robots and the humanoid, from "
        f"the table above; small robots pay more per IMU for each step's fixed cost (ur5e: "
        f"{ur['network']['seconds']:.0f} s for {ur['imus']} IMUs; {b.provenance('topology')})."
    )


def _topology_doc(b: _Bench) -> str:
    lines = [
        f"Measured with {b.provenance('topology')}:",
        "",
        "| robot | fast exact | fast CPU s | shortest exact fast | network exact | network CPU s (×fast) "
        "| smallest true / largest false feature | network-paper | mlp |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in _topology_rows(b):
        lines.append(
            _row(
                [
                    r["robot"],
                    _exact(r["fast"]),
                    f"{r['fast']['seconds']:.2f}",
                    f"{r['shortest']:g} s",
                    _exact(r["network"]),
                    f"{r['network']['seconds']:.0f} ({_ratio(r, 'network'):.0f}×)",
                    f"{r['network']['true_min']:.3f} / {r['network']['false_max']:.3f}",
                    _exact(r["network-paper"]),
                    _exact(r["mlp"]),
                ]
            )
        )
    return "\n".join(lines)


def _topology_short(b: _Bench) -> str:
    rows = _topology_rows(b)
    seeds = _topology_settings(b)["seeds"]
    all_exact = all(r["fast"]["exact"] == r["fast"]["runs"] for r in rows)
    return (
        f"On the catalog robots with observable excitation `fast` is exact on "
        f"{'all' if all_exact else 'not all'} {seeds} seeds from "
        f"{_span([r['shortest'] for r in rows], 'g')} s of data ({b.provenance('topology')})."
    )


def _topology_paper(b: _Bench) -> str:
    rows = _topology_rows(b)
    runs = sum(r["network-paper"]["runs"] for r in rows)
    exact = sum(r["network-paper"]["exact"] for r in rows)
    weak = _weakest(rows)
    return (
        f"In the benchmark ({b.provenance('topology')}) `network-paper` is exact in {exact} of the {runs} "
        "runs, with a smallest true feature of "
        f"{_span([r['network-paper']['true_min'] for r in rows], '.3f')}; "
        f"`network`'s thinnest margin is the {weak['robot']}'s (smallest true "
        f"{weak['network']['true_min']:.3f} against largest false {weak['network']['false_max']:.3f} over "
        f"{weak['network']['runs']} seeds)."
    )


def _sim_rows(b: _Bench) -> tuple[list[dict[str, str]], list[dict[str, str]]]:
    return b.table("sim.md", "robot"), b.table("sim.md", "farm")


def _sim_farm(farm: list[dict[str, str]]) -> dict[tuple[str, str], dict[str, str]]:
    return {(r["chunk"], r["read-ahead"]): r for r in farm}


def _sim_readme(b: _Bench) -> str:
    robots, farm = _sim_rows(b)
    f = _sim_farm(farm)
    ahead, none = f[("0.1 s", "1 s")], f[("0.1 s", "0 s")]
    target = re.search(r"meets (\d+)×", ahead["× real time"]) or re.search(r"(\d+)×\)", ahead["× real time"])
    tgt = float(target.group(1)) if target else 20.0
    paper = [r for r in robots if r["robot"].startswith("paper-")]
    other = [r for r in robots if not r["robot"].startswith("paper-")]
    n = ahead["robots"]
    pj, pk = paper[0]["joints"], paper[0]["IMUs"]
    xs = [_num(r["× real time"]) for r in paper]
    settings = re.search(r"IMU model `([\w-]+)`, excitation `([\w-]+)`, (\d+) Hz", b.text("sim.md"))
    if settings is None:
        raise ValueError("sim.md: settings line not found")
    model, excitation, hz = settings.groups()
    lines = [
        f"Measured with {b.provenance('sim')}, {hz} Hz, `{model}` IMU model, `{excitation}` excitation, "
        f"load average {b.load('sim')}. Target: a {n}-robot farm of paper robots at ≥ {tgt:g}× real time — "
        f"{'met' if _num(ahead['× real time']) >= tgt else 'missed'} ({_num(ahead['× real time']):.1f}× "
        f"with the farm's 1 s read-ahead; {_num(none['× real time']):.1f}× without it).",
        "",
        "| | samples/s | × real time |",
        "|---|---:|---:|",
        _row(
            [
                f"one paper robot ({pj} joints, {pk} IMUs)",
                "–".join(_int(round(x, -2)) for x in _minmax(_num(r["samples/s"]) for r in paper)),
                f"{min(xs):.0f}–{max(xs):.0f}×",
            ]
        ),
        _row(
            [
                " / ".join(r["robot"] for r in other),
                " / ".join(r["samples/s"] for r in other),
                " / ".join(r["× real time"] for r in other),
            ]
        ),
    ]
    for r in farm:
        chunk = f"{r['chunk']} chunks"
        if r["chunk"] == "0.1 s":
            chunk += ", 1 s read-ahead" if r["read-ahead"] != "0 s" else ", no read-ahead"
        lines.append(
            _row(
                [
                    f"farm of {r['robots']} {r['farm']}, {chunk}",
                    r["samples/s (all robots)"],
                    f"{_num(r['× real time']):.1f}×",
                ]
            )
        )
    return "\n".join(lines)


def _minmax(values: Iterable[float]) -> tuple[float, float]:
    vals = list(values)
    return min(vals), max(vals)


def _sim_doc(b: _Bench) -> str:
    robots, farm = _sim_rows(b)
    f = _sim_farm(farm)
    paper = [_num(r["× real time (CPU)"]) for r in robots if r["robot"].startswith("paper-")]
    x = {k: f"{_num(r['× real time (CPU)']):.1f}×" for k, r in f.items()}
    return (
        f"In the run recorded there ({b.provenance('sim')}), a paper robot runs at "
        f"{min(paper):.0f}–{max(paper):.0f}× real time on its own CPU time, the "
        f"{f[('0.1 s', '1 s')]['robots']}-robot farm at {x[('0.1 s', '1 s')]} (0.1 s chunks, read-ahead), "
        f"{x[('0.1 s', '0 s')]} (0.1 s chunks, none) and {x[('1 s', '1 s')]} (1 s chunks); wall-clock "
        "figures depend on what else runs."
    )


def _store(b: _Bench) -> dict:
    return b.json("store.json")  # type: ignore[return-value]


def _store_readme(b: _Bench) -> str:
    d = _store(b)
    names = {"sqlite": "SQLite", "postgresql": "PostgreSQL"}
    rows = sorted(d["rows"], key=lambda r: (r["backend"] != "sqlite", not r["path"].startswith("pipeline")))
    target = d["target_multiple"] * d["imus"] * d["rate_hz"]
    best = max((r for r in rows if r["backend"] == "sqlite"), key=lambda r: r["realtime_multiple"])
    met = best["realtime_multiple"] >= d["target_multiple"]
    how = "through the ingest pipeline" if best["path"].startswith("pipeline") else f"with {best['path']}"
    lines = [
        f"Measured with {b.provenance('store')}, load average {d['load_average']:.1f}: a {d['imus']}-IMU, "
        f"{d['joints']}-joint robot at {d['rate_hz']:g} Hz, {d['device_seconds']:g} s of device time; window "
        f"read = the latest {d['window_seconds']:g} s as arrays. Target ≥ {d['target_multiple']:g}× real "
        f"time ({_int(target)} IMU samples/s) on SQLite — {'met ' + how if met else 'missed'}.",
        "",
        f"| backend | path | IMU samples/s | × real time | {d['window_seconds']:g} s window read |",
        "|---|---|---:|---:|---:|",
    ]
    for r in rows:
        path = (
            "pipeline (queue → coalescing writer)"
            if r["path"].startswith("pipeline") and r["backend"] == "sqlite"
            else "pipeline"
            if r["path"].startswith("pipeline")
            else f"`write_many`, {r['path'].removeprefix('write_many ')} per transaction"
        )
        read = f"{r['window_read_ms']:.0f} ms" if r["window_read_ms"] is not None else ""
        lines.append(
            _row(
                [
                    names.get(r["backend"], r["backend"]),
                    path,
                    _int(r["imu_samples_per_s"]),
                    f"{r['realtime_multiple']:.0f}×",
                    read,
                ]
            )
        )
    return "\n".join(lines).replace("|  |", "| |")


def _store_doc(b: _Bench) -> str:
    d = _store(b)
    rows = {(r["backend"], r["path"].split()[0]): r for r in d["rows"]}
    parts = []
    for backend, name in (("sqlite", "SQLite"), ("postgresql", "PostgreSQL")):
        pipe, direct = rows.get((backend, "pipeline")), rows.get((backend, "write_many"))
        if pipe and direct:
            parts.append(
                f"{name} {pipe['realtime_multiple']:.0f}× real time through the pipeline and "
                f"{direct['realtime_multiple']:.0f}× with `write_many`, a {d['window_seconds']:g} s window "
                f"read in {pipe['window_read_ms']:.0f} ms"
            )
    return (
        f"`bodyhealth bench store` ingests a {d['imus']}-IMU, {d['joints']}-joint robot at "
        f"{d['rate_hz']:g} Hz into SQLite and PostgreSQL, through the pipeline and through direct "
        f"`write_many` calls with one second per transaction, and times reading a "
        f"{d['window_seconds']:g} s window. In the run recorded "
        f"there ({b.provenance('store')}, load average {d['load_average']:.1f}): " + "; ".join(parts) + "."
    )


def _load_readme(b: _Bench) -> str:
    d = b.json("load.json")
    at_target = [r for r in d["rows"] if r["offered_rps"] == d["target_rps"]]

    def who(r: dict) -> str:
        kind = "threads" if r.get("client") == "threads" else "locust users"
        return f"{r.get('users', '?')} {kind}"

    verdicts = [
        ("met" if r["p99_ms"] <= d["target_p99_ms"] and not r["failures"] else "missed")
        + f" from {who(r)} (p99 {r['p99_ms']:g} ms)"
        for r in at_target
    ]
    lines = [
        f"Measured with {b.provenance('load')}, load average {d['load_average']:.1f}: `bodyhealth serve "
        f"--demo` (SQLite, the farm ingesting in real time, the worker learning, the networks training) "
        f"under mixed reads from a load generator on the same machine, {d['seconds']:g} s per run. "
        f"Target: p99 ≤ {d['target_p99_ms']:g} ms at {d['target_rps']:g} rps — "
        + ("; ".join(verdicts) or "not measured at the target rate")
        + ".",
        "",
        "| offered rps | clients | achieved rps | p50 | p95 | p99 | failures | service CPU s/s "
        "| frames stored/s | network retrains |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in d["rows"]:
        lines.append(
            f"| {r['offered_rps']:g} | {who(r)} | {r['achieved_rps']:.1f} | {r['p50_ms']:g} ms "
            f"| {r['p95_ms']:g} ms | {r['p99_ms']:g} ms | {r['failures']} | {r['service_cpu_per_s']:.2f} "
            f"| {r['frames_stored_per_s']:.0f} | {r.get('network_retrains', 0)} |"
        )
    return "\n".join(lines)


def _writes_doc(b: _Bench) -> str:
    d = b.json("writes.json")
    default = d["default_interval_s"]
    rows = {(r["backend"], r["commit_interval_s"]): r for r in d["rows"]}
    parts = []
    for backend, name in (("sqlite", "SQLite"), ("postgresql", "PostgreSQL")):
        at, none = rows.get((backend, default)), rows.get((backend, 0.0))
        if at and none:
            parts.append(
                f"{name} {at['journal_amplification']:.2f}x journal ({at['total_amplification']:.2f}x in "
                f"total) at {default:g} s, against {none['journal_amplification']:.2f}x "
                f"({none['total_amplification']:.2f}x) when every queued batch is committed at once"
            )
    return (
        f"`bodyhealth bench writes` streams {d['robots']} robots ({d['joints']} joints, {d['imus']} IMUs, "
        f"100 Hz) in real time through the ingest pipeline and counts the bytes written per byte of "
        f"frames, for each commit interval (target: journal at most {d['target']:g}x at the default "
        f"{default:g} s). In the run recorded there ({b.provenance('writes')}, load average "
        f"{d['load_average']:.1f}): " + "; ".join(parts) + "."
    )


def _ingest(b: _Bench) -> dict:
    return b.json("ingest.json")  # type: ignore[return-value]


def _ingest_rows(d: dict) -> dict[str, dict]:
    return {r["path"]: r for r in d["rows"]}


def _ingest_readme(b: _Bench) -> str:
    d = _ingest(b)
    rows = _ingest_rows(d)
    fps = d["can_frames_per_sample"] * d["rate"]
    shown = [
        ("serial pty (emulator process)", "serial frames, pty"),
        ("CAN slcan pty (emulator process)", "CAN classic, slcan over pty"),
        ("CAN FD slcan pty (emulator process)", "CAN FD, slcan over pty"),
        ("CAN decode+regroup (memory)", "CAN decode + regroup only"),
    ]
    worst = min(rows[k]["x_real_time"] for k, _ in shown)
    lines = [
        f"Measured with {b.provenance('ingest')}, load average {b.load('ingest')}: the simulated humanoid "
        f"({d['joints']} joints, {d['imus']} IMUs, {d['rate']:g} Hz: {_int(fps)} classic CAN frames/s "
        "in real time). The emulator runs in its own process and writes a pty; the ingestor reads it. "
        f"Target ≥ {INGEST_TARGET_X:g}× real time — "
        f"{'met on every path' if worst >= INGEST_TARGET_X else 'missed'}.",
        "",
        "| path | frames/s | × real time |",
        "|---|---:|---:|",
    ]
    for key, label in shown:
        r = rows[key]
        x = r["x_real_time"]
        lines.append(_row([label, _int(r["frames_per_s"]), f"{x:.1f}×" if x < 100 else f"{x:.0f}×"]))
    return "\n".join(lines)


def _ingest_doc(b: _Bench) -> str:
    d = _ingest(b)
    rows = _ingest_rows(d)
    fd = re.search(r"(\d+) CAN FD frames", b.text("ingest.md"))
    shown = [
        ("serial pty (emulator process)", "serial pty (emulator process)"),
        (
            "CAN slcan pty (emulator process)",
            f"CAN slcan pty, classic layout ({d['can_frames_per_sample']} frames/sample)",
        ),
        (
            "CAN FD slcan pty (emulator process)",
            f"CAN FD slcan pty ({fd.group(1) if fd else '?'} frames/sample)",
        ),
        ("CAN decode+regroup (memory)", "CAN decode+regroup alone (memory)"),
    ]
    lines = [
        f"Measured with {b.provenance('ingest')}, load average {b.load('ingest')}:",
        "",
        "| path | frames/s (wall) | × real time (wall) | frames per CPU-second | × real time per core |",
        "|---|---:|---:|---:|---:|",
    ]
    for key, label in shown:
        r = rows[key]
        lines.append(
            _row(
                [
                    label,
                    _int(r["frames_per_s"]),
                    f"{r['x_real_time']:.1f}",
                    _int(r["frames_per_cpu_s"]),
                    f"{r['x_real_time_per_core']:.1f}",
                ]
            )
        )
    regroup = rows["CAN decode+regroup (memory)"]
    us = 1e6 / regroup["frames_per_cpu_s"]
    fps = d["can_frames_per_sample"] * d["rate"]
    lines += [
        "",
        f"Decoding and regrouping cost {us:.2f} µs of CPU per frame; the rest of the CAN path is "
        "python-can's per-frame work (slcan line parsing, `Message` objects, the notifier thread). A "
        "1 Mbit/s classic bus delivers at most about 8,000 frames/s — "
        f"{'less' if fps > 8000 else 'more'} than the humanoid's "
        f"{_int(fps)} — so on classic CAN such a robot "
        f"{'needs two buses anyway; the CAN FD layout carries it on one' if fps > 8000 else 'fits one bus'}.",
    ]
    return "\n".join(lines)


def _trials(b: _Bench) -> dict[str, dict]:
    """Every per-trial discrepancy.json under docs/bench/sim2real/, by trial name."""
    base = b.root / BENCH / "sim2real"
    return {
        p.parent.name: b.json(f"sim2real/{p.parent.name}/discrepancy.json")
        for p in sorted(base.glob("*/discrepancy.json"))
    }  # type: ignore[misc]


def _cause(d: dict, effect: str) -> dict | None:
    return next((c for c in d["causes"] if c["effect"] == effect), None)


def _sim2real_stats(b: _Bench) -> dict:
    trials = _trials(b)
    n = len(trials)
    causes = {
        e: {t: c for t, d in trials.items() if (c := _cause(d, e)) is not None}
        for e in ("time_offset", "lever_arm", "gyro_bias", "acc_bias", "gyro_scale")
    }
    lever = {t: np.asarray(c["params"]["meters"]) for t, c in causes["lever_arm"].items()}
    rows = b.table("sim2real.md", "trial")
    wall = [_num(r["analysis s (cpu s)"]) for r in rows]
    cpu = [float(re.search(r"\(([0-9.]+)\)", r["analysis s (cpu s)"]).group(1)) for r in rows]  # type: ignore[union-attr]
    transfer = [r["transfer gain"] for r in rows]
    tr_med = [_num(t) for t in transfer]
    tr_lo = [float(re.search(r"\(([-0-9.]+)–", t).group(1)) for t in transfer]  # type: ignore[union-attr]
    tr_hi = [float(re.search(r"–([-0-9.]+),", t).group(1)) for t in transfer]  # type: ignore[union-attr]
    held = {t: d["held_out"] for t, d in trials.items()}
    best = max(held, key=lambda t: held[t]["gain"])
    minutes = statistics.mean(d["meta"]["duration_s"] for d in trials.values()) / 60
    rate = statistics.median(
        d["params"]["noise"]["rate_hz"] for d in trials.values() if "noise" in d["params"]
    )
    limit = re.search(r"limit (\d+) s", b.text("sim2real.md"))
    return {
        "n": n,
        "causes": causes,
        "offset_ms": [c["params"]["seconds"] * 1e3 for c in causes["time_offset"].values()],
        "offset_gain": [c["gain"] for c in causes["time_offset"].values()],
        "lever_mm": [float(np.linalg.norm(v)) * 1e3 for v in lever.values()],
        "lever_z": sum(int(np.argmax(np.abs(v)) == 2) for v in lever.values()),
        "gyro_bias": [float(np.linalg.norm(c["params"]["vector"])) for c in causes["gyro_bias"].values()],
        "acc_bias": [float(np.linalg.norm(c["params"]["vector"])) for c in causes["acc_bias"].values()],
        "gyro_bias_sessions": sorted({t.rsplit("_", 1)[1] for t in causes["gyro_bias"]}),
        "held_gain": [h["gain"] for h in held.values()],
        "best": best,
        "best_held": held[best],
        "minutes": minutes,
        "rate": rate,
        "wall": wall,
        "cpu": cpu,
        "tr_med": tr_med,
        "tr_lo": tr_lo,
        "tr_hi": tr_hi,
        "limit": limit.group(1) if limit else "30",
    }


def _sessions(names: list[str]) -> str:
    return (
        f"session {names[0]}"
        if len(names) == 1
        else "sessions " + ", ".join(names[:-1]) + f" and {names[-1]}"
    )


def _sim2real_prov(b: _Bench) -> str:
    return (
        f"`{b.command('sim2real')}` on {b.machine('sim2real')}; the `{BENCH}/sim2real/*/discrepancy.json` "
        f"reports and `{BENCH}/sim2real.md`"
    )


def _sim2real_readme(b: _Bench) -> str:
    s = _sim2real_stats(b)
    n, c = s["n"], s["causes"]
    trial = s["best"].split("_")[0]
    h = s["best_held"]
    return "\n".join(
        [
            f"Measured with {_sim2real_prov(b)}: all {n} shared BROAD trials (one real IMU + optical motion "
            f"capture, ≈{s['minutes']:.1f} min each). Gains are measured on held-out time blocks, never on "
            "the fit data; *transfer* simulates the other trials of the same IMU session with the fitted "
            "model vs the default model (1 − MSE ratio).",
            "",
            "| | result |",
            "|---|---|",
            f"| named in {len(c['time_offset'])}/{n} trials | `time_offset` "
            f"{_span(s['offset_ms'], '.1f')} ms (the IMU lags the motion capture by about one "
            f"{s['rate']:.1f} Hz sample) |",
            f"| named in {len(c['lever_arm'])}/{n} trials | `lever_arm` {_span(s['lever_mm'], '.1f')} mm, "
            f"largest along the sensor z axis in {s['lever_z']}/{len(c['lever_arm'])} |",
            f"| named in some | `gyro_bias` {_span(s['gyro_bias'], '.3f')} rad/s "
            f"({len(c['gyro_bias'])}/{n}), "
            f"`acc_bias` {_span(s['acc_bias'], '.2f')} m/s² ({len(c['acc_bias'])}/{n}), `gyro_scale` "
            f"({len(c['gyro_scale'])}/{n}) |",
            f"| held-out gain per trial | {_span(s['held_gain'])} (trial {trial}: gyro RMS "
            f"{h['gyro_rms_before']:.3f} → {h['gyro_rms_after']:.3f} rad/s) |",
            f"| transfer gain to other trials of the session | median per fitted trial "
            f"{_span(s['tr_med'])} (range {min(s['tr_lo']):.2f}–{max(s['tr_hi']):.2f})"
            f"{', never worse' if min(s['tr_lo']) >= 0 else ''} |",
            f"| analysis time per trial | median {statistics.median(s['wall']):.1f} s, max "
            f"{max(s['wall']):.1f} s wall clock (limit {s['limit']} s); CPU median "
            f"{statistics.median(s['cpu']):.1f} s |",
        ]
    )


def _sim2real_doc(b: _Bench) -> str:
    s = _sim2real_stats(b)
    n, c = s["n"], s["causes"]
    trial = s["best"].split("_")[0]
    h = s["best_held"]
    lo, hi = min(s["tr_lo"]), max(s["tr_hi"])
    return "\n".join(
        [
            f"In short (measured with {_sim2real_prov(b)}):",
            "",
            f"* **{'Every' if len(c['time_offset']) == n else 'Not every'} trial** names a **time offset** "
            "of "
            f"{_span(s['offset_ms'], '.1f')} ms (the IMU samples lag the motion capture by about one sample "
            f"at {s['rate']:.1f} Hz; held-out gain {_span(s['offset_gain'])} of the ideal model's residual "
            f"energy on its own), and {len(c['lever_arm'])} of {n} a **lever arm** of "
            f"{_span(s['lever_mm'], '.1f')} mm, largest along the sensor's z axis in {s['lever_z']} of "
            f"{len(c['lever_arm'])}. Beside them: a small gyro bias "
            f"({_span(s['gyro_bias'], '.3f')} rad/s, "
            f"{len(c['gyro_bias'])} trials, {_sessions(s['gyro_bias_sessions'])}), an accelerometer bias "
            f"({_span(s['acc_bias'], '.2f')} m/s², {len(c['acc_bias'])} trials) and, in "
            f"{len(c.get('gyro_scale', []))} trials, a gyro scale error.",
            f"* Total held-out gain {_span(s['held_gain'])} per trial (best: trial {trial}, gyro RMS "
            f"{h['gyro_rms_before']:.3f} → {h['gyro_rms_after']:.3f} rad/s). What remains is mostly "
            "accelerometer residual above a few Hz, where differentiating the motion capture twice is itself "
            "the error.",
            "* **Transfer:** the model fitted on one trial and simulated on the other trials of the same "
            f"IMU session removes {lo * 100:.0f}–{hi * 100:.0f} % of the default model's error (median per "
            f"fitting trial {_span(s['tr_med'])}){'; never negative' if lo >= 0 else ''}.",
            f"* Analysis {_span(s['wall'], '.1f')} s wall clock per trial "
            f"(≈ {s['minutes']:.1f} min of data), "
            f"{_span(s['cpu'], '.1f')} s CPU; limit {s['limit']} s.",
        ]
    )


def _sim2real_example(b: _Bench) -> str:
    name = "02_undisturbed_slow_rotation_B"
    text = b.text(f"sim2real/{name}/report.md")
    m = re.search(r"```\n(.*?)```", text, re.S)
    if m is None:
        raise ValueError(f"sim2real/{name}/report.md has no output block")
    return "\n".join(
        [
            f"Example output (trial {name.split('_')[0]}, slow rotations, session {name[-1]}; from "
            f"{BENCH}/sim2real/{name}/report.md, written by `{b.command('sim2real')}` on "
            f"{b.machine('sim2real')}):",
            "",
            "```",
            m.group(1).rstrip("\n"),
            "```",
        ]
    )


def _sim2real_detect_doc(b: _Bench) -> str:
    from bench.sim2real_detect import summary

    d = b.json("sim2real-detect.json")
    return "\n".join([f"Measured with `{d['command']}` on {d['machine']}:", "", *summary(d)])


def _sim2real_encoders_doc(b: _Bench) -> str:
    from bench.sim2real_encoders import summary

    d = b.json("sim2real-encoders.json")
    return "\n".join([f"Measured with `{d['command']}` on {d['machine']}:", "", *summary(d)])


def _gravity_runs(b: _Bench) -> list[dict]:
    return b.json("gravity.json")  # type: ignore[return-value]


def _gravity_named(runs: list[dict], reference: str) -> list[dict]:
    out = []
    for d in runs:
        c = next((c for c in d["analyses"][reference]["causes"] if c["effect"] == "gravity"), None)
        if c is not None:
            out.append(c)
    return out


def _gravity_intro(b: _Bench, runs: list[dict]) -> str:
    s = runs[0]["settings"]
    seeds = sorted({d["seed"] for d in runs})
    return (
        f"{', '.join(dict.fromkeys(d['robot'] for d in runs))}; {s['seconds']:g} s at 100 Hz, "
        f"`{s['imu_model']}` IMU model, seeds {seeds[0]}–{seeds[-1]}, {s['epochs']} epochs"
    )


def _gravity_readme(b: _Bench) -> str:
    from bench.gravity import summary_table

    runs = _gravity_runs(b)
    gain = [d["residual_gain"] for d in runs]
    cpu = {r: [d["cpu_s"] for d in runs if d["robot"] == r] for r in dict.fromkeys(d["robot"] for d in runs)}
    n_an = len(runs[0]["imus_analysed"]) * 2
    return "\n".join(
        [
            "The paper's sensor networks trained without gravity (Eq. 11) and with it (Eq. 24) on simulated "
            f"robot recordings ({_gravity_intro(b, runs)}; measured with {b.provenance('gravity')}). The "
            "analyzer names the cause of the Eq. 11 residual on the robot's exact kinematics; topology is "
            "compared with the ground truth.",
            "",
            summary_table(runs),
            "",
            f"Eq. 24 removes {_span([100 * g['acc'] for g in gain], '.1f')} % of the accelerometer residual "
            f"energy and {_span([100 * g['gyro'] for g in gain], '.0f')} % of the gyro's; "
            + ", ".join(f"{_span(v, '.0f')} CPU s per {r} run" for r, v in cpu.items())
            + f" (two trainings, two topologies, {n_an} analyses).",
        ]
    )


def _gravity_doc(b: _Bench) -> str:
    from bench.gravity import summary_table

    runs = _gravity_runs(b)
    n = len(runs)
    kin = _gravity_named(runs, "kinematics")
    f11 = [d["forms"]["eq11"] for d in runs]
    f24 = [d["forms"]["eq24"] for d in runs]
    gain = [d["residual_gain"] for d in runs]
    cpu = {r: [d["cpu_s"] for d in runs if d["robot"] == r] for r in dict.fromkeys(d["robot"] for d in runs)}
    n_an = len(runs[0]["imus_analysed"]) * 2
    missed = [d for d in runs if not d["forms"]["eq11"]["accuracy"]["exact"]]
    acc = [(d, d["forms"]["eq11"]["accuracy"]) for d in missed]
    miss = "; ".join(
        f"{d['robot']} seed {d['seed']}: {100 * a['joint_parent']:.0f} % of joint parents, "
        f"{100 * a['imu_joint']:.0f} % of IMU joints right"
        for d, a in acc
    )
    ex11 = sum(x["accuracy"]["exact"] for x in f11)
    ex24 = sum(x["accuracy"]["exact"] for x in f24)
    return "\n".join(
        [
            f"Measured with {b.provenance('gravity')} ({_gravity_intro(b, runs)}):",
            "",
            summary_table(runs),
            "",
            f"* Gravity is named on the Eq. 11 residual on the exact kinematics in {len(kin)} of {n} runs, "
            f"with {_span([c['params']['norm'] for c in kin])} m/s² and "
            f"{_span([c['params']['angle_to_recording_deg'] for c in kin], '.1f')}° from the recording's "
            f"gravity, by {_span([c['imus'] for c in kin], 'd')} of "
            f"{_span([c['of'] for c in kin], 'd')} IMUs.",
            f"* Eq. 24 removes {_span([100 * g['acc'] for g in gain], '.1f')} % of the accelerometer "
            f"residual energy ({_span([x['acc_rms'] for x in f11])} → "
            f"{_span([x['acc_rms'] for x in f24])} m/s²) and "
            f"{_span([100 * g['gyro'] for g in gain], '.0f')} % of the gyro residual's.",
            f"* Topology: Eq. 11 is exact in {ex11} of {n} runs"
            + (f" ({miss})" if miss else "")
            + f"; Eq. 24 in "
            f"{ex24} of {n}. "
            + ", ".join(f"{_span(v, '.0f')} s CPU per {r} run" for r, v in cpu.items())
            + f" (both trainings, both topologies, {n_an} analyses).",
        ]
    )


def _gravity_networks(b: _Bench) -> str:
    runs = _gravity_runs(b)
    net = _gravity_named(runs, "network")
    return (
        "* The gravity case's cause on the Eq. 11 *networks* (no model given) is named but its magnitude "
        "is not gravity's: trained without the term, the networks bend their accelerations and biases "
        "towards it (a joint moving sinusoidally has `θ̈ ∝ −θ`, so `J θ̈` can mimic a "
        "configuration-dependent signal): "
        f"on them gravity is named in {len(net)} of {len(runs)} bench runs, with only "
        f"{_span([c['params']['norm'] for c in net])} m/s² "
        f"({b.provenance('gravity')}). Pass `--model` to name it on the exact kinematics."
    )


def _realism(b: _Bench) -> str:
    d = b.json("realism.json")
    assert isinstance(d, dict)
    summary, rows, catalog = d["summary"], d["rows"], d.get("catalog", [])
    sizes = sorted({r["joints"] for r in rows})
    n_robots = len({(r["joints"], r["robot"]) for r in rows})
    parts = []
    for method, s in summary.items():
        if not s["robots"]:
            continue
        big = [r for r in rows if r["method"] == method and r["joints"] == sizes[-1] and r["cell"] != "ideal"]
        cost = (
            f"; {np.mean([r['cpu_s'] for r in big]):.1f} CPU s per robot on average and at most "
            f"{max(r['cpu_s'] for r in big):.1f} at {sizes[-1]} joints (sensed cells)"
            if big
            else ""
        )
        skew = s["max_abs_skew_err_ms_where_exact"]
        one = s.get("single_clock") or {}
        parts.append(
            f"`{method}`: {s['exact']} of {s['robots']} estimates exact, {s['undetermined']} "
            f"undetermined, {s['wrong']} confidently wrong"
            + (f", skew within {skew:.2f} ms wherever exact" if skew is not None else "")
            + cost
            + (
                f"; in single-clock form (one `t`, positions only) {one['exact']} of {one['robots']} "
                f"exact, {one['undetermined']} undetermined, {one['wrong']} confidently wrong"
                if one.get("robots")
                else ""
            )
        )
    text = (
        f"On random MuJoCo robots of {', '.join(map(str, sizes))} joints ({n_robots} "
        f"robots, {len({r['cell'] for r in rows})} sensing conditions; {b.provenance('realism')}): "
        + "; ".join(parts)
        + "."
    )
    if catalog:
        exact = sum(c["verdict"] == "exact" for c in catalog)
        text += (
            f" The catalog on the robot preset: {exact} of {len(catalog)} exact with `fast`, skew error at "
            f"most {max(abs(c['skew_err_ms']) for c in catalog):.2f} ms."
        )
    return text


def _shapes(b: _Bench) -> str:
    d = b.json("shapes.json")
    assert isinstance(d, dict)
    rows, summary = d["rows"], d["summary"]
    joints = [r["joints"] for r in rows]
    parts = []
    for shape, s in summary.items():
        text = (
            f"{shape}: {s['exact']} exact, {s['undetermined']} undetermined ({s['named_joints']} joints "
            f"named to move), {s['wrong']} confidently wrong"
        )
        if s.get("axis_deg_median") is not None:
            text += (
                f"; on the true tree axis error median {s['axis_deg_median']:.2f}° (the gyro's reading "
                f"{fmt(s['gyro_axis_deg_median'])}°), lever arm median {fmt(s['lever_mm_median'], '.1f')} "
                f"mm over {s['imus']} IMUs, {s['converged']} converged"
            )
        parts.append(text)
    still = sum(len(r["still_joints"]) for r in rows if r["shape"] == rows[0]["shape"])
    return (
        f"On {len({r['robot'] for r in rows})} random robots of {min(joints)}-{max(joints)} joints from the "
        "independent generator (`bench/generator.py`, no code shared with `simulators/`; "
        f"{still} joints jammed, true rate RMS under 0.05 rad/s; {b.provenance('shapes')}): "
        + "; ".join(parts)
        + "."
    )


def _excitation(b: _Bench) -> str:
    d = b.json("excitation.json")
    assert isinstance(d, dict)
    s, runs = d["summary"], d["runs"]
    wrong = {
        m: sum(r["wrong"] for r in runs if r["motion"] == m) for m in dict.fromkeys(r["motion"] for r in runs)
    }
    later = s["planned_later_than_one_at_a_time"]
    return (
        f"On {s['robots']} robots ({b.provenance('excitation')}): the planned motion reached the unique, "
        f"right tree {fmt(s['median_topology_ratio'], '.2f')}x sooner than the default random motion "
        f"(median) and converged geometry {fmt(s['median_geometry_ratio'], '.2f')}x sooner; it was later "
        f"than one joint at a time on {len(later)} robot(s); unique but wrong trees at some prefix: "
        + ", ".join(f"{m} {n}" for m, n in wrong.items())
        + f"; {s['violations']} limit violations; planning took at most "
        f"{fmt(s['plan_cpu_s_max'], '.2f')} CPU s."
    )


def _calibration(b: _Bench) -> str:
    d = b.json("calibration.json")
    assert isinstance(d, dict)
    parts = []
    for answer, a in d["summary"].items():
        if not isinstance(a, dict) or "forms" not in a:
            continue
        forms = a["forms"].values()
        n = sum(f["exact"] + f["undetermined"] + f["wrong"] for f in forms)
        top = [r for r in a["reliability"] if r["from"] >= 0.99]
        sure = f"{sum(r['right'] for r in top)} of {sum(r['parts'] for r in top)}"
        parts.append(
            f"{answer}: exact {sum(f['exact'] for f in forms)} of {n}, undetermined "
            f"{sum(f['undetermined'] for f in forms)}, confidently wrong {sum(f['wrong'] for f in forms)}; "
            f"parts at confidence ≥ 0.99 right: {sure}"
        )
    return f"On {len(d['rows'])} robot-forms ({b.provenance('calibration')}): " + "; ".join(parts) + "."


def _import_doc(b: _Bench) -> str:
    d: dict = b.json("import.json")  # type: ignore[assignment]
    labels = {"ros1": "ROS 1 (.bag)", "sqlite3": "ROS 2 sqlite3", "mcap": "ROS 2 MCAP"}
    biggest = max(m["seconds"] for m in d["memory"])
    mem = {m["format"]: m for m in d["memory"] if m["seconds"] == biggest}
    lines = [
        f"Measured with {b.provenance('import')}, load average {b.load('import')}: a {d['seconds']:g} s "
        f"bag of {d['joints']} joints and {d['imus']} IMUs; the plain loop reads and deserializes every "
        f"message with `rosbags` and keeps nothing; the import writes the `.npz` too. Peak resident "
        f"memory while importing a {biggest:g} s bag into a file, against the bag's size and what the "
        "recording's numbers would take in memory:",
        "",
        "| format | import msgs/s | import MB/s | plain loop msgs/s | import / loop time | bag MB "
        "| peak RSS MB | arrays MB |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in d["rows"]:
        m = mem[r["format"]]
        lines.append(
            _row(
                [
                    labels[r["format"]],
                    _int(r["import_msgs_per_s"]),
                    f"{r['import_mb_per_s']:.1f}",
                    _int(r["floor_msgs_per_s"]),
                    f"{r['import_over_floor']:.2f}",
                    _int(m["bag_mb"]),
                    f"{m['rss_peak_mb']:.0f}",
                    f"{m['recording_arrays_mb']:.0f}",
                ]
            )
        )
    return "\n".join(lines)


def _scale_doc(b: _Bench) -> str:
    from bench.fleet import ALONE, LOADED

    d: dict = b.json("fleet.json")  # type: ignore[assignment]
    rows = [r for r in d["rows"] if r["beside"] == LOADED]
    alone = [r for r in d["rows"] if r["beside"] == ALONE]
    # Workers on machines of their own (the distributed setup) train at the rate measured alone, when
    # the bench measured it; else at the best rate measured beside ingest and the API.
    basis = alone or rows
    best = max(basis, key=lambda r: r["retrains_per_hour"] / r["workers"])
    per_worker = best["retrains_per_hour"] / best["workers"]
    warm = d["warm_cpu_s"]
    per_robot_sps = statistics.median(r["ingest_samples_per_s"] / r["robots"] for r in rows)
    speed = ", ".join(f"{n} robots {s:g}x" for n, s in d["speedup_2_over_1"].items())
    speed_alone = ", ".join(f"{n} robots {s:g}x" for n, s in d["speedup_2_over_1_alone"].items())
    alone_lines = (
        [
            "",
            "With the training alone on the machine (no ingest, no API), as on workers of their own:",
            "",
            "| robots | workers | retrains/hour | CPU s per retrain (median) |",
            "|---:|---:|---:|---:|",
            *[
                _row([r["robots"], r["workers"], _int(r["retrains_per_hour"]), r["cpu_s_median"]])
                for r in alone
            ],
        ]
        if alone
        else []
    )
    lines = [
        f"From {b.provenance('fleet')} (load average {d['load_average']} at its end): {d['robot']} "
        f"robots ({d['joints']} joints, {d['imus']} IMUs), {d['window_s']:g} s windows. A warm retrain "
        f"took {warm:g} CPU s (median), a robot's first, cold one {d['cold_cpu_s']:g} CPU s. Per fleet "
        "size and workers, on this machine, with ingest and the API running beside the training:",
        "",
        "| robots | workers | retrains/hour | ingest lag median s | ingest lag max s | API p99 ms |",
        "|---:|---:|---:|---:|---:|---:|",
        *[
            _row(
                [
                    r["robots"],
                    r["workers"],
                    _int(r["retrains_per_hour"]),
                    r["ingest_lag_s_median"],
                    r["ingest_lag_s_max"],
                    f"{r['api_p99_ms']:g}",
                ]
            )
            for r in rows
        ],
        *alone_lines,
        "",
        f"2 workers against 1: {speed} with ingest and the API beside"
        + (f"; {speed_alone} with the training alone" if speed_alone else "")
        + ". Extrapolated from the per-robot costs: workers at the best rate measured per worker "
        f"{'with the training alone ' if alone else ''}({per_worker:,.0f} retrains/hour, {best['robots']} "
        f"robots on {best['workers']}), CPU cores from the warm retrain's CPU seconds, and "
        f"{per_robot_sps:,.0f} IMU samples/s per robot:",
        "",
        "| robots | retrain every | retrains/hour needed | workers (measured rate) | CPU cores (warm CPU s) "
        "| IMU samples/s into the store |",
        "|---:|---|---:|---:|---:|---:|",
    ]
    for n in (1_000, 10_000):
        for every, label in ((60.0, "1 min (default)"), (600.0, "10 min"), (3600.0, "1 h")):
            need = n * 3600.0 / every
            lines.append(
                _row(
                    [
                        _int(n),
                        label,
                        _int(need),
                        _int(-(-need // per_worker)),
                        _int(-(-need * warm // 3600.0)),
                        _int(n * per_robot_sps),
                    ]
                )
            )
    return "\n".join(lines)


def _kinematics_rows(b: _Bench) -> dict:
    d = b.json("kinematics.json")
    assert isinstance(d, dict)
    return d


def _kinematics_line(r: dict) -> str:
    return (
        f"axis error median {r['axis_median_deg']:.2f}° (max {r['axis_max_deg']:.2f}°), "
        f"{r['axis_within_2std']:.0%} of them within twice their std, where the axis the gyro reports is "
        f"off by {r['gyro_axis_median_deg']:.2f}° (max {r['gyro_axis_max_deg']:.2f}°; its sensitivity "
        f"matrix alone: {r['gyro_floor_median_deg']:.2f}°, max {r['gyro_floor_max_deg']:.2f}°); lever arm "
        f"median {r['lever_median_mm']:.1f} mm (max {r['lever_max_mm']:.1f} mm); "
        f"{r['converged']} of {r['imus_on_links']} IMUs converged"
    )


def _kinematics(b: _Bench) -> str:
    d = _kinematics_rows(b)
    s, t = d["settings"], d["targets"]
    longest = d["summary"][-1]
    verdict = []
    for key, name, unit, got in (
        ("axis_deg", "axis", "°", (longest["axis_median_deg"], longest["axis_max_deg"])),
        ("lever_mm", "lever arm", " mm", (longest["lever_median_mm"], longest["lever_max_mm"])),
    ):
        ok = got[0] is not None and got[0] <= t[key][0] and got[1] <= t[key][1]
        verdict.append(
            f"{name} median ≤ {t[key][0]:g}{unit} (max {t[key][1]:g}{unit}) — {'met' if ok else 'not met'}"
        )
    lines = [
        f"Measured with {b.provenance('kinematics')}: random trees of "
        f"{', '.join(map(str, s['joints']))} joints ({s['robots_per_size']} per size), `{s['imu_model']}` "
        f"IMU errors, `{s['sensing']}` sensing preset, the tree learned by `fast`. From "
        f"{longest['seconds']} s: {_kinematics_line(longest)}. Targets from 60 s: "
        + "; ".join(verdict)
        + ".",
        "",
        "| seconds | converged | axis median / max ° | within 2 std | gyro axis median / max ° "
        "| lever median / max mm | CPU s |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in d["summary"]:
        lines.append(
            _row(
                [
                    r["seconds"],
                    f"{r['converged']} / {r['imus_on_links']}",
                    f"{r['axis_median_deg']:.2f} / {r['axis_max_deg']:.2f}",
                    f"{r['axis_within_2std']:.0%}",
                    f"{r['gyro_axis_median_deg']:.2f} / {r['gyro_axis_max_deg']:.2f}",
                    f"{r['lever_median_mm']:.1f} / {r['lever_max_mm']:.1f}",
                    f"{r['cpu_s_median']:.2f}",
                ]
            )
        )
    pub = "; ".join(
        f"{p['source']}, {p['what']}: "
        + ", ".join(
            x
            for x in (
                f"{p['axis_deg']:g}°" if p["axis_deg"] is not None else "",
                f"{p['lever_mm']:g} mm" if p["lever_mm"] is not None else "",
            )
            if x
        )
        for p in d["published"]
    )
    lines += ["", f"Published figures, on other robots and sensors: {pub}."]
    return "\n".join(lines)


def _kinds(cat: list[dict]) -> str:
    """The kinds of the catalog part's false findings, counted ("4 imu_shifted"; "none")."""
    from collections import Counter

    n = Counter(f["kind"] for r in cat for w in r["nominal_findings"] for f in w)
    return ", ".join(f"{v} {k}" for k, v in sorted(n.items())) or "none"


def _drift(b: _Bench, name: str = "drift") -> str:
    """``bench drift``'s run in ``docs/bench/<name>.json``, in the frame it ran in."""
    from bench.drift import _change, _elsewhere, service_text

    d = b.json(f"{name}.json")
    assert isinstance(d, dict)
    cat = d["catalog"]
    windows = sum(r["nominal_windows"] for r in cat)
    false = sum(len(n) for r in cat for n in r["nominal_findings"])
    parts = []
    for kind, label in (("imu_rotated", "turn of one IMU"), ("axis_changed", "bend of its joint's axis")):
        runs = [g for r in cat for g in r["damages"] if g["kind"] == kind]
        seen = [
            c for g in runs if g["first_right"] and (c := _change(g["findings"][0]["detail"])) is not None
        ]
        mag = runs[0]["magnitude"] if runs else 0
        right = sum(g["first_right"] for g in runs)
        text = f"a {mag:g}° {label}: first found on its part on {right} of {len(runs)}"
        if seen:
            text += (
                f" (change seen {min(c[0] for c in seen):.2f} to {max(c[0] for c in seen):.2f}°, "
                f"limits {min(c[1] for c in seen):.2f} to {max(c[1] for c in seen):.2f}°)"
            )
        parts.append(text)
    slack = [g for r in cat for g in r["damages"] if g["kind"] == "backlash"]
    if slack:
        parts.append(
            f"a {slack[0]['magnitude']:g}° dead band in that joint: first found on its part on "
            f"{sum(g['first_right'] for g in slack)} of {len(slack)}"
        )
    for mm in sorted({g["magnitude"] for r in cat for g in r["damages"] if g["kind"] == "imu_shifted"}):
        runs = [g for r in cat for g in r["damages"] if g["kind"] == "imu_shifted" and g["magnitude"] == mm]
        parts.append(
            f"a {mm:g} mm slide of that IMU: found on {sum(g['found'] for g in runs)} of {len(runs)}"
        )
    lines = [
        f"Measured with {b.provenance(name)}, "
        + ("in the accelerometers' frame" if d.get("accelerometer_frame") else "about the gyros' axes")
        + f": {len(cat)} catalog robots "
        f"({', '.join(r['robot'] for r in cat)}), `robot` sensing preset, MPU-6050 IMUs kept across the "
        f"run, {d['window_s']:g} s windows: {false} false findings in {windows} healthy windows compared "
        f"with each robot's first ({_kinds(cat)}); " + "; ".join(parts) + ". Two estimates are compared "
        "here by their stated stds, slides too; the service judges slides against the baseline's pool "
        "(below) and raises none from two estimates."
    ]
    p = d.get("pooled")
    if p is not None:
        found = "; ".join(
            f"{g['mm']:g} mm of {g['imu']} ({g['lever_arm_mm']:.0f} mm from its axis) "
            + (
                f"after {g['windows_to_finding']} window{'s' if g['windows_to_finding'] > 1 else ''}"
                if g["windows_to_finding"]
                else f"not within {p['windows_after']} windows"
            )
            for g in p["slides"]
        )
        lines += [
            "",
            f"Slides judged on pooled lever arms ({p['robot']}, {p['n_base']} estimates against the mean of "
            f"the newest k, every k up to {p['n_recent']}, each without its farthest): "
            f"{sum(len(n) for n in p['nominal_findings'])} "
            "findings in "
            f"{p['nominal_windows']} healthy windows judged{_elsewhere(d, 'pooled')}; found: {found}.",
        ]
    if d["service"] is not None:
        lines += ["", service_text(d)]
    return "\n".join(lines)


def _share_within(rows: list[dict]) -> str:
    """The share of same-link rotations within twice their std, over every robot's (pair-weighted)."""
    n = sum(r["same_link_fixed"] for r in rows)
    k = sum(r["same_link_fixed_within_2std"] * r["same_link_fixed"] for r in rows)
    return f"{k / n:.1%}"


def _rotations(b: _Bench) -> str:
    d = b.json("rotations.json")
    assert isinstance(d, dict)
    rows = d["summary"]
    s = d["settings"]
    det = [r for r in rows if r["determined"]]
    und = [r for r in rows if r["undetermined"]]
    fixed = [r for r in rows if r["same_link_fixed"]]

    def ext(rs: list[dict], key: str, f=max) -> float:
        return f(r[key] for r in rs if r[key] is not None)

    lines = [
        f"Measured with {b.provenance('rotations')}: {len(rows)} catalog robots, {s['seeds']} recordings "
        f"of {s['seconds']:g} s each, `{s['imu_model']}` IMU errors, `{s['sensing']}` sensing preset, the "
        f"true tree. {sum(r['determined'] for r in rows)} rotations from the parent were reported "
        f"determined, the largest {ext(det, 'determined_max_deg'):.2f}° off; "
        f"{sum(r['undetermined'] for r in rows)} undetermined, on "
        f"{', '.join(r['robot'] for r in und) or 'none'}, "
        + (
            f"{ext(und, 'undetermined_min_deg', min):.1f} to {ext(und, 'undetermined_max_deg'):.1f}° off, "
            f"with turn stds of {ext(und, 'undetermined_turn_std_min_deg', min):.2f}° and more"
            if und
            else "none"
        )
        + f". Same-link rotations at rank 2 or more: {sum(r['same_link_fixed'] for r in rows)}, the largest "
        f"{ext(fixed, 'same_link_fixed_max_deg'):.2f}° off, {_share_within(fixed)} of them within twice "
        f"their std; {sum(r['same_link_rank1'] for r in rows)} at rank 1.",
        "",
        "| robot | determined | max error ° | undetermined | their errors ° | same link rank ≥ 2 "
        "| max error ° | rank 1 |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        span = (
            "—"
            if not r["undetermined"]
            else f"{r['undetermined_min_deg']:.1f}–{r['undetermined_max_deg']:.1f}"
        )
        lines.append(
            f"| {r['robot']} | {r['determined']} | {fmt(r['determined_max_deg'])} | {r['undetermined']} "
            f"| {span} | {r['same_link_fixed']} | {fmt(r['same_link_fixed_max_deg'])} "
            f"| {r['same_link_rank1']} |"
        )
    lines += ["", "![rotations](bench/rotations.png)"]
    return "\n".join(lines)


def _lever_budget(b: _Bench) -> str:
    from bench.lever_budget import summary

    d = b.json("lever-budget.json")
    assert isinstance(d, dict)
    conds = d["conditions"]
    first = next(iter(conds.values()))["frames"]["gyro"]
    windows = max(r["windows"] for r in first.values())
    lines = [
        f"Measured with {b.provenance('lever-budget')}: the lever arms of the {d['robot']}'s {len(first)} "
        f"IMUs in {windows} windows of {d['window_s']:g} s, the same motion under each condition. Scatter: "
        "RMS distance of one window's lever arm from the windows' mean, median over the IMUs (largest); "
        "understated: IMUs scattering more than twice the std they state.",
        "",
        "| condition | gyros' frame | understated | accelerometers' frame | understated |",
        "|---|---:|---:|---:|---:|",
    ]
    for label, c in conds.items():
        cells = []
        for frame in ("gyro", "accelerometer"):
            s = summary(c, frame)
            cells += [
                f"{s['scatter_median_mm']:.1f} ({s['scatter_max_mm']:.1f}) mm",
                f"{s['understated']} of {s['imus']}",
            ]
        lines.append(_row([label, *cells]))
    far = []
    for label, said in (("MPU-6050", "the MPU-6050 model"), ("noise only", "its noise alone")):
        g = conds.get(label, {}).get("frames", {}).get("gyro")
        if g:
            n = max(g, key=lambda k: g[k]["worst_mm"])
            far.append(f"{g[n]['worst_mm']:.1f} mm ({n}) with {said}")
    if far:
        head = "The farthest one window's lever arm came from its IMU's mean, about the gyros' axes: "
        lines += ["", head + "; ".join(far) + "."]
    return "\n".join(lines)


@dataclass(frozen=True)
class Figure:
    """One marked block: which doc, which marker id, which bench file it is rendered from, and how."""

    doc: str
    id: str
    source: str
    render: Callable[[_Bench], str]


def _f(doc: str, id_: str, source: str, render: Callable[[_Bench], str]) -> Figure:
    return Figure(doc, id_, f"{BENCH}/{source}" if source else BENCH, render)


#: Every figure block in the docs. A block in a doc that is not listed here, or listed and missing
#: from its doc, fails the check as much as a stale one.
FIGURES: tuple[Figure, ...] = (
    _f("README.md", "bench-machines", "", _machines),
    _f("README.md", "algebra", "algebra.md", _algebra),
    _f("README.md", "topology", "topology.json", _topology_readme_all),
    _f("README.md", "scaling", "scaling.json", _scaling_readme),
    _f("README.md", "network-cost", "topology.json", _network_cost),
    _f("README.md", "sim", "sim.md", _sim_readme),
    _f("README.md", "store", "store.json", _store_readme),
    _f("README.md", "ingest", "ingest.json", _ingest_readme),
    _f("README.md", "load", "load.json", _load_readme),
    _f("README.md", "sim2real", "sim2real", _sim2real_readme),
    _f("README.md", "gravity", "gravity.json", _gravity_readme),
    _f("docs/algebra.md", "algebra", "algebra.md", _algebra_doc),
    _f("docs/topology.md", "fast-shortest", "topology.json", _topology_short),
    _f("docs/topology.md", "network-paper", "topology.json", _topology_paper),
    _f("docs/topology.md", "scaling", "scaling.json", _scaling_doc),
    _f("docs/topology.md", "topology", "topology.json", _topology_doc),
    _f("docs/simulators.md", "sim", "sim.md", _sim_doc),
    _f("docs/store.md", "store", "store.json", _store_doc),
    _f("docs/store.md", "writes", "writes.json", _writes_doc),
    _f("docs/transports.md", "ingest", "ingest.json", _ingest_doc),
    _f("docs/sim2real.md", "example", "sim2real/02_undisturbed_slow_rotation_B/report.md", _sim2real_example),
    _f("docs/sim2real.md", "results", "sim2real", _sim2real_doc),
    _f("docs/sim2real.md", "detect", "sim2real-detect.json", _sim2real_detect_doc),
    _f("docs/sim2real.md", "encoders", "sim2real-encoders.json", _sim2real_encoders_doc),
    _f("docs/sim2real.md", "gravity", "gravity.json", _gravity_doc),
    _f("docs/sim2real.md", "gravity-networks", "gravity.json", _gravity_networks),
    _f("docs/topology.md", "realism", "realism.json", _realism),
    _f("README.md", "realism", "realism.json", _realism),
    _f("docs/topology.md", "shapes", "shapes.json", _shapes),
    _f("docs/excitation.md", "excitation", "excitation.json", _excitation),
    _f("docs/topology.md", "calibration", "calibration.json", _calibration),
    _f("docs/recording-format.md", "import", "import.json", _import_doc),
    _f("docs/kinematics.md", "kinematics", "kinematics.json", _kinematics),
    _f("README.md", "kinematics", "kinematics.json", _kinematics),
    _f("docs/kinematics.md", "drift", "drift.json", _drift),
    _f(
        "docs/kinematics.md",
        "drift-accelerometer-frame",
        "drift-accelerometer-frame/drift.json",
        lambda b: _drift(b, "drift-accelerometer-frame/drift"),
    ),
    _f("docs/kinematics.md", "lever-budget", "lever-budget.json", _lever_budget),
    _f("docs/kinematics.md", "rotations", "rotations.json", _rotations),
    _f("docs/scale.md", "fleet", "fleet.json", _scale_doc),
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
    b = _Bench(Path(root))
    return {(f.doc, f.id): _body(f.render(b)) for f in FIGURES}


def _render_each(root: Path) -> tuple[dict[tuple[str, str], str], list[str]]:
    """Like :func:`render`, but a bench file that cannot be read becomes a problem line, not a crash."""
    b = _Bench(root)
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
