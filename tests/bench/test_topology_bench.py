"""``bodyhealth bench topology`` bookkeeping: the feature-separation numbers it reports per run."""

from __future__ import annotations

import argparse
from types import SimpleNamespace

import numpy as np
import pytest

from bench import topology as bench


def _run(features: np.ndarray, dependency: np.ndarray, undetermined: list[int]) -> SimpleNamespace:
    return SimpleNamespace(features=features, dependency=dependency, undetermined=np.array(undetermined, int))


def test_separation_counts_wrong_entries_over_decided_joints_only() -> None:
    truth = np.array([[1, 0, 0], [1, 1, 0], [1, 1, 1]], dtype=bool)
    feats = np.array([[0.9, 0.05, 0.5], [0.6, 0.4, 0.01], [0.5, 0.08, 0.6]])
    dep = feats > 0.1
    rec = SimpleNamespace(truth_dependency=truth)
    # joint 2 undetermined: its column (a false 0.5 that binarizes as true) is left out
    sep = bench._separation(_run(feats, dep, [2]), rec)
    assert sep == {"wrong": 1, "true_min": pytest.approx(0.08), "false_max": pytest.approx(0.05)}
    sep_all = bench._separation(_run(feats, dep, []), rec)
    assert sep_all["wrong"] == 2 and sep_all["false_max"] == pytest.approx(0.5)


def test_report_has_a_separation_table_for_learned_methods(tmp_path) -> None:
    row = {
        "robot": "paper-1",
        "joints": 5,
        "imus": 10,
        "shortest": 3.0,
        "fast": {"exact": 2, "runs": 2, "seconds": 0.1},
        "network": {
            "exact": 1,
            "runs": 2,
            "seconds": 5.0,
            "wrong": [0, 3],
            "true_min": 0.121,
            "false_max": 0.065,
        },
    }
    args = argparse.Namespace(
        robots="paper-1", seeds=2, seconds=60.0, epochs=40, jobs=1, durations="1,3", out=tmp_path / "t.md"
    )
    md = bench._write([row], ["fast", "network"], args).read_text()
    assert "| paper-1 | 5 | 10 | 2/2 | 1/2 | 3 | 0.10 | 50× (5 s) |" in md
    assert "| paper-1 | 0.121 / 0.065 (0, 3) |" in md
