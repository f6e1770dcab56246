"""The README's table of which machine and command produced each bench file."""

from __future__ import annotations

from bench.figures.files import BENCH, BenchFiles, table_row

__all__ = ["figure"]


def figure(b: BenchFiles) -> str:
    names = [p.stem for p in sorted((b.root / BENCH).glob("*.md")) if p.stem != "README"]
    lines = [
        "| bench | machine | command | load average when it ran |",
        "|---|---|---|---:|",
    ]
    for name in names:
        lines.append(table_row([f"`{name}`", b.machine(name), f"`{b.command(name)}`", b.load(name) or "—"]))
    return "\n".join(lines)
