"""The ``bodyhealth`` command line.

Each subcommand lives in its own module under :mod:`cli.commands` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` (``args -> exit code``). Modules are
imported lazily by name so a heavy dependency (torch, mujoco) is only loaded by the commands that use it.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from cli.machine_output import json_stdout

__all__ = ["COMMAND_MODULES", "build_parser", "main"]

#: Subcommand modules, in the order ``--help`` lists them.
COMMAND_MODULES: tuple[str, ...] = (
    "robots",
    "simulate",
    "topology",
    "kinematics",
    "excite",
    "diff",
    "inject",
    "serve",
    "db",
    "import_",
    "export",
    "sim2real",
    "bench",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bodyhealth",
        description="Robot body-health monitoring: learn the body schema from IMUs and encoders, "
        "compare it with a baseline, raise damage alerts.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        modname = f"cli.commands.{name}"
        try:
            module = importlib.import_module(modname)
        except ModuleNotFoundError as err:
            if err.name == modname:  # command not shipped in this build
                continue
            raise
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose > 1 else logging.INFO if args.verbose else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        if getattr(args, "json", False):  # the JSON alone on stdout; solver logs go to stderr
            with json_stdout():
                return int(args.func(args) or 0)
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except (ValueError, OSError) as err:
        print(f"bodyhealth {args.command}: error: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
