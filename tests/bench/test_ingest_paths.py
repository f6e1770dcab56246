"""The in-memory decode paths of ``bodyhealth bench ingest`` decode every sample they are given.

The bench drives the serial encoder and the CAN assembler directly (no pty); a change to either that
the bench does not follow would otherwise surface only when someone runs the benchmark.
"""

from __future__ import annotations

import pytest

from bench.ingest import _can_decode, _recording, _serial_decode


@pytest.fixture(scope="module")
def rec():
    return _recording(n=7, k=5, rate=100.0, seconds=2.0, seed=0)


def test_serial_decode_counts_every_sample(rec) -> None:
    _, _, n = _serial_decode(rec)
    assert n == rec.n_samples == 200


@pytest.mark.parametrize("layout", ["classic", "fd"])
def test_can_decode_counts_every_sample(rec, layout: str) -> None:
    _, _, n = _can_decode(rec, layout)
    assert n == rec.n_samples
