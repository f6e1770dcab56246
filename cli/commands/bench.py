"""``bodyhealth bench NAME|all``: run a benchmark and write its results file under docs/bench/."""

from __future__ import annotations

import argparse
import importlib

from bench import BENCHMARKS

__all__ = ["register"]


def _available() -> dict[str, object]:
    mods = {}
    for name in BENCHMARKS:
        modname = f"bench.{name}"
        try:
            mods[name] = importlib.import_module(modname)
        except ModuleNotFoundError as err:
            if err.name != modname:
                raise
    return mods


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run benchmarks; results go to docs/bench/")
    bsub = p.add_subparsers(dest="bench", metavar="NAME", required=True)
    mods = _available()
    for name, mod in mods.items():
        # argparse %-formats help strings; a docstring's '%' (e.g. "10 % of bits") must reach it escaped
        summary = (mod.__doc__ or "").strip().splitlines()[0] if mod.__doc__ else None
        bp = bsub.add_parser(name.rstrip("_"), help=summary.replace("%", "%%") if summary else None)
        mod.add_arguments(bp)  # type: ignore[attr-defined]
        bp.set_defaults(func=_runner(mod))
    ap = bsub.add_parser("all", help="every benchmark with its default settings")
    ap.set_defaults(func=lambda args: _run_all(mods))


def _runner(mod: object):
    def run(args: argparse.Namespace) -> int:
        path = mod.run(args)  # type: ignore[attr-defined]
        print(f"results written to {path}")
        return 0

    return run


def _run_all(mods: dict[str, object]) -> int:
    for name, mod in mods.items():
        parser = argparse.ArgumentParser()
        mod.add_arguments(parser)  # type: ignore[attr-defined]
        print(f"== bench {name.rstrip('_')}")
        _runner(mod)(parser.parse_args([]))
    return 0
