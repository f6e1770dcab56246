"""Shared fixtures. Tests that draw random cases log their seed so a failure can be replayed."""

from __future__ import annotations

import os
import random

import numpy as np
import pytest


@pytest.fixture
def seed(request: pytest.FixtureRequest) -> int:
    """A fresh seed per test (``BODYHEALTH_TEST_SEED`` pins it), printed so a failure can be replayed."""
    value = int(os.environ.get("BODYHEALTH_TEST_SEED", random.SystemRandom().randrange(2**31)))
    print(f"{request.node.nodeid}: seed={value} (replay with BODYHEALTH_TEST_SEED={value})")
    return value


@pytest.fixture
def rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)
