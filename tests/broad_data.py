"""Where the tests find the BROAD trials, and the one skip every BROAD test uses when they are absent.

The measured trials (Laidig, Caruso, Cereatti, Seel, "BROAD—A Benchmark for Robust Inertial
Orientation Estimation", Data 6(7), 2021, CC BY 4.0) are too large for the repository; they live in
the team's shared folder beside the checkout. ``BODYHEALTH_BROAD_DIR`` points elsewhere (another
layout, a CI cache). One lookup, so that every BROAD test looks in the same place and skips for the
same stated reason, which CI (``BODYHEALTH_CI=1``) turns into a failure.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest

__all__ = ["BROAD_ENV", "broad_dir", "broad_marks", "broad_trial", "needs_broad"]

#: Environment variable naming the directory that holds the BROAD ``*.hdf5`` trials.
BROAD_ENV = "BODYHEALTH_BROAD_DIR"

F = TypeVar("F", bound=Callable[..., object])

_REPO_ROOT = Path(__file__).resolve().parents[1]


def broad_dir() -> Path:
    """``$BODYHEALTH_BROAD_DIR`` when set, else ``<repo root>/../shared/data/broad``."""
    env = os.environ.get(BROAD_ENV)
    if env:
        return Path(env)
    return _REPO_ROOT.parent / "shared" / "data" / "broad"


def broad_trial(name: str) -> Path:
    """The path of one trial (``name`` with or without ``.hdf5``); it may not exist."""
    return broad_dir() / (name if name.endswith(".hdf5") else f"{name}.hdf5")


def broad_marks(*names: str) -> list[pytest.MarkDecorator]:
    """The marks of a module (``pytestmark``) that reads the BROAD trials ``names``.

    The ``broad`` marker selects or deselects them (``-m "not broad"``); the skip names the
    directory searched and the trials missing, so a skipped run says what to copy where.
    """
    missing = [n for n in names if not broad_trial(n).is_file()]
    reason = (
        f"BROAD data missing: {', '.join(missing)} not in {broad_dir()} "
        f"(set {BROAD_ENV} to the directory of the BROAD *.hdf5 trials)"
    )
    return [pytest.mark.broad, pytest.mark.skipif(bool(missing), reason=reason)]


def needs_broad(*names: str) -> Callable[[F], F]:
    """:func:`broad_marks` as a decorator, for one test in a module that mostly needs no data."""

    def apply(test: F) -> F:
        for mark in broad_marks(*names):
            test = mark(test)
        return test

    return apply
