"""Figures from ``bench algebra`` (docs/bench/algebra.md): the MILP correction's timings."""

from __future__ import annotations

import re

from bench.figures.files import BenchFiles, num, span, table_row

__all__ = ["doc", "readme"]


def readme(b: BenchFiles) -> str:
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
            table_row(
                [
                    r["N"],
                    r["flipped bits"],
                    f"{num(r['correct: median s (min-max)']):.3f}",
                    r["distance"],
                    f"{r['trellis (Alg. 3) alone: s']} / {r['trellis distance']}",
                ]
            )
        )
    return "\n".join(lines)


def doc(b: BenchFiles) -> str:
    rows = b.table("algebra.md", "N")
    sparse = b.table("algebra.md", "N", 1)
    m = re.search(r"(\d+)% of the N x N matrix bits flipped, median of (\d+)", b.text("algebra.md"))
    assert m is not None
    sizes = ", ".join(r["N"] for r in rows)
    worst = max(rows, key=lambda r: int(r["N"]))
    return (
        f"In the run recorded there ({b.provenance('algebra')}), N = {sizes} with {m.group(1)} % of the "
        f"bits flipped (median of {m.group(2)}): `correct` takes "
        f"{span([num(r['correct: median s (min-max)']) for r in rows], '.3f')} s and ends at "
        f"distance {worst['distance']} for N = {worst['N']} ({worst['flipped bits']} bits flipped), "
        f"where the trellis alone stops at {worst['trellis distance']}; with N//4 bits flipped the "
        f"exact stage certified {span([num(r['certified']) for r in sparse], '.0f')} of "
        f"{span([num(r['certified'].split('/')[1]) for r in sparse], '.0f')} trees per N."
    )
