"""Reading the bench files under docs/bench/ and formatting their numbers, for the figure renderers."""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from functools import cache
from pathlib import Path

__all__ = ["BENCH", "BenchFiles", "int_text", "md_tables", "num", "span", "table_row"]


#: Where the bench files live, relative to the repository root.
BENCH = "docs/bench"


_MACHINE = re.compile(r"(?:Machine|Measured on): (.+?Python \d+(?:\.\d+)*)")


_COMMAND = re.compile(r"`(bodyhealth bench [^`]+)`")


_LOAD = re.compile(r"[Ll]oad average[^0-9]{0,40}([0-9]+(?:\.[0-9]+)?)")


class BenchFiles:
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
        return md_tables(self.text(rel), first_header)[nth]


def md_tables(text: str, first_header: str) -> list[list[dict[str, str]]]:
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


def num(cell: str) -> float:
    """The first number in a table cell ('38,723', '30.6× (meets 20×)', '0.152 (0.120-0.184)')."""
    m = re.search(r"-?[0-9][0-9,]*(?:\.[0-9]+)?", cell)
    if m is None:
        raise ValueError(f"no number in {cell!r}")
    return float(m.group(0).replace(",", ""))


def span(values: Iterable[float], fmt: str = ".2f") -> str:
    """'lo–hi', or one value when both print alike."""
    vals = list(values)
    lo, hi = f"{min(vals):{fmt}}", f"{max(vals):{fmt}}"
    return lo if lo == hi else f"{lo}–{hi}"


def int_text(x: float) -> str:
    return f"{round(x):,}"


def table_row(cells: Iterable[object]) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"
