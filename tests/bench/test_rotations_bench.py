"""``bodyhealth bench rotations``: on a robot with a vertical root axis the rotations that axis leaves
open are the ones reported undetermined, and on one with horizontal roots none is; the run writes its
table, JSON and plot."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from bench import rotations as bench

pytestmark = pytest.mark.slow


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    return p.parse_args(list(argv))


def test_short_run_splits_determined_from_undetermined(tmp_path: Path) -> None:
    """Seed 0 of the UR5e (vertical shoulder pan) and the quadruped (horizontal hips): fixed, so the
    numbers are the same on every run."""
    md = bench.run(_args("--robots", "ur5e,quadruped", "--seeds", "1", "--out", str(tmp_path)))
    d = json.loads((tmp_path / "rotations.json").read_text())
    ur5e, quadruped = d["summary"]
    assert (ur5e["robot"], quadruped["robot"]) == ("ur5e", "quadruped")
    # the UR5e's shoulder-lift IMUs sit under the vertical pan: left open, and far off
    assert ur5e["undetermined"] == 2 and ur5e["undetermined_min_deg"] > 90.0
    assert ur5e["undetermined_turn_std_min_deg"] > 1.0
    assert ur5e["determined"] == 8 and ur5e["determined_max_deg"] < 2.0
    assert ur5e["same_link_rank1"] == 1 and ur5e["same_link_fixed"] == 5
    assert ur5e["same_link_fixed_within_2std"] == 1.0  # their std holds the gyros' cross-axis errors
    # gravity across the quadruped's hips fixes every turn under them
    assert quadruped["undetermined"] == 0 and quadruped["determined"] == 16
    assert quadruped["determined_max_deg"] < 1.0 and quadruped["determined_turn_std_max_deg"] < 0.2
    assert quadruped["same_link_rank1"] == 4
    assert (tmp_path / "rotations.png").stat().st_size > 10_000
    text = md.read_text()
    assert d["command"] in text and "| ur5e | 8 |" in text
