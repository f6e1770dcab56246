"""Arguments of a benchmark as ``bodyhealth bench NAME ...`` would parse them."""

from __future__ import annotations

import argparse
from types import ModuleType

__all__ = ["bench_args"]


def bench_args(module: ModuleType, *argv: str) -> argparse.Namespace:
    """``argv`` parsed by the parser ``module.add_arguments`` builds (defaults for the rest)."""
    p = argparse.ArgumentParser()
    module.add_arguments(p)
    return p.parse_args(list(argv))
