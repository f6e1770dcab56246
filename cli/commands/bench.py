"""``bodyhealth bench NAME|all``: run a benchmark and write its results file under docs/bench/.

The benchmark modules import the whole stack (torch, MuJoCo, the service, Dask), so building the
``bodyhealth`` parser must not import them: each one's help line is read from its source file, and its
arguments are added only when ``bench NAME`` is actually parsed (:class:`LazyParser`).
"""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from bench import BENCHMARKS

__all__ = ["LazyParser", "register"]


class LazyParser(argparse.ArgumentParser):
    """A sub-parser whose arguments are added by ``loader(self)`` the first time it parses.

    ``bodyhealth --help`` and ``bodyhealth bench --help`` only list sub-parsers, so a benchmark
    module is imported only when its own command line (or its ``--help``) is parsed.
    """

    def __init__(
        self, *args: Any, loader: Callable[[argparse.ArgumentParser], None] | None = None, **kw: Any
    ):
        super().__init__(*args, **kw)
        self._loader = loader

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        loader, self._loader = self._loader, None
        if loader is not None:
            loader(self)
        return super().parse_known_args(args, namespace)


def _summary(modname: str) -> str | None:
    """First docstring line of ``modname`` read from its source without importing it (None: not shipped)."""
    spec = importlib.util.find_spec(modname)
    if spec is None or not spec.origin:
        return None
    doc = ast.get_docstring(ast.parse(Path(spec.origin).read_text(encoding="utf-8")))
    return doc.strip().splitlines()[0] if doc and doc.strip() else ""


def _load(name: str) -> Callable[[argparse.ArgumentParser], None]:
    def load(parser: argparse.ArgumentParser) -> None:
        mod = importlib.import_module(f"bench.{name}")
        mod.add_arguments(parser)  # type: ignore[attr-defined]
        parser.set_defaults(func=_runner(mod))

    return load


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run benchmarks; results go to docs/bench/")
    bsub = p.add_subparsers(dest="bench", metavar="NAME", required=True, parser_class=LazyParser)
    shipped = []
    for name in BENCHMARKS:
        summary = _summary(f"bench.{name}")
        if summary is None:  # benchmark not shipped in this build
            continue
        shipped.append(name)
        # argparse %-formats help strings; a docstring's '%' (e.g. "10 % of bits") must reach it escaped
        bsub.add_parser(name.rstrip("_"), help=summary.replace("%", "%%") or None, loader=_load(name))
    ap = bsub.add_parser("all", help="every benchmark with its default settings")
    ap.set_defaults(func=lambda args: _run_all(shipped))


def _runner(mod: ModuleType) -> Callable[[argparse.Namespace], int]:
    def run(args: argparse.Namespace) -> int:
        path = mod.run(args)  # type: ignore[attr-defined]
        print(f"results written to {path}")
        return 0

    return run


def _run_all(names: Sequence[str]) -> int:
    for name in names:
        mod = importlib.import_module(f"bench.{name}")
        parser = argparse.ArgumentParser()
        mod.add_arguments(parser)  # type: ignore[attr-defined]
        print(f"== bench {name.rstrip('_')}")
        _runner(mod)(parser.parse_args([]))
    return 0
