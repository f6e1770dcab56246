"""Figures from ``bench sim`` (docs/bench/sim.md): simulation and farm rates."""

from __future__ import annotations

import re
from collections.abc import Iterable

from bench.figures.files import BenchFiles, int_text, num, table_row

__all__ = ["doc", "readme"]


def _rows(b: BenchFiles) -> tuple[list[dict[str, str]], list[dict[str, str]]]:
    return b.table("sim.md", "robot"), b.table("sim.md", "farm")


def _farm(farm: list[dict[str, str]]) -> dict[tuple[str, str], dict[str, str]]:
    return {(r["chunk"], r["read-ahead"]): r for r in farm}


def readme(b: BenchFiles) -> str:
    robots, farm = _rows(b)
    f = _farm(farm)
    ahead, none = f[("0.1 s", "1 s")], f[("0.1 s", "0 s")]
    target = re.search(r"meets (\d+)×", ahead["× real time"]) or re.search(r"(\d+)×\)", ahead["× real time"])
    tgt = float(target.group(1)) if target else 20.0
    paper = [r for r in robots if r["robot"].startswith("paper-")]
    other = [r for r in robots if not r["robot"].startswith("paper-")]
    n = ahead["robots"]
    pj, pk = paper[0]["joints"], paper[0]["IMUs"]
    xs = [num(r["× real time"]) for r in paper]
    settings = re.search(r"IMU model `([\w-]+)`, excitation `([\w-]+)`, (\d+) Hz", b.text("sim.md"))
    if settings is None:
        raise ValueError("sim.md: settings line not found")
    model, excitation, hz = settings.groups()
    lines = [
        f"Measured with {b.provenance('sim')}, {hz} Hz, `{model}` IMU model, `{excitation}` excitation, "
        f"load average {b.load('sim')}. Target: a {n}-robot farm of paper robots at ≥ {tgt:g}× real time — "
        f"{'met' if num(ahead['× real time']) >= tgt else 'missed'} ({num(ahead['× real time']):.1f}× "
        f"with the farm's 1 s read-ahead; {num(none['× real time']):.1f}× without it).",
        "",
        "| | samples/s | × real time |",
        "|---|---:|---:|",
        table_row(
            [
                f"one paper robot ({pj} joints, {pk} IMUs)",
                "–".join(int_text(round(x, -2)) for x in _minmax(num(r["samples/s"]) for r in paper)),
                f"{min(xs):.0f}–{max(xs):.0f}×",
            ]
        ),
        table_row(
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
            table_row(
                [
                    f"farm of {r['robots']} {r['farm']}, {chunk}",
                    r["samples/s (all robots)"],
                    f"{num(r['× real time']):.1f}×",
                ]
            )
        )
    return "\n".join(lines)


def _minmax(values: Iterable[float]) -> tuple[float, float]:
    vals = list(values)
    return min(vals), max(vals)


def doc(b: BenchFiles) -> str:
    robots, farm = _rows(b)
    f = _farm(farm)
    paper = [num(r["× real time (CPU)"]) for r in robots if r["robot"].startswith("paper-")]
    x = {k: f"{num(r['× real time (CPU)']):.1f}×" for k, r in f.items()}
    return (
        f"In the run recorded there ({b.provenance('sim')}), a paper robot runs at "
        f"{min(paper):.0f}–{max(paper):.0f}× real time on its own CPU time, the "
        f"{f[('0.1 s', '1 s')]['robots']}-robot farm at {x[('0.1 s', '1 s')]} (0.1 s chunks, read-ahead), "
        f"{x[('0.1 s', '0 s')]} (0.1 s chunks, none) and {x[('1 s', '1 s')]} (1 s chunks); wall-clock "
        "figures depend on what else runs."
    )
