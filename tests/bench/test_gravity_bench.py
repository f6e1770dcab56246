"""``bodyhealth bench gravity``: kept runs are reported without retraining; a short real run names gravity."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bench import gravity as bench

KEPT = Path(__file__).resolve().parents[2] / "docs" / "bench" / "gravity.json"


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    return p.parse_args(list(argv))


def test_kept_runs_are_reported_not_retrained(tmp_path, monkeypatch) -> None:
    shutil.copy(KEPT, tmp_path / "gravity.json")
    runs = json.loads(KEPT.read_text())
    monkeypatch.setattr(bench, "run_one", lambda *a: pytest.fail(f"retrained {a}"))
    md = bench.run(_args("--robots", "ur5e", "--seeds", "0,1,2", "--out", str(tmp_path)))
    text = md.read_text()
    ur5e = [d for d in runs if d["robot"] == "ur5e"]
    med = np.median([d["forms"]["eq11"]["acc_rms"] for d in ur5e])
    assert f"| ur5e | {len(ur5e)} | {med:.2f} → " in text
    # every kept run has a row, with its seed and its CPU seconds
    for d in runs:
        assert f"| {d['robot']} | {d['seed']} | {d['forms']['eq11']['acc_rms']:.3f} → " in text
    assert (tmp_path / "gravity.png").stat().st_size > 5000
    assert json.loads((tmp_path / "gravity.json").read_text()) == runs


@pytest.mark.slow
def test_a_short_run_names_gravity_on_the_kinematics(tmp_path) -> None:
    md = bench.run(
        _args("--robots", "ur5e", "--seeds", "3", "--seconds", "12", "--epochs", "3", "--out", str(tmp_path))
    )
    (d,) = json.loads((tmp_path / "gravity.json").read_text())
    assert (d["robot"], d["seed"], d["settings"]["seconds"], d["settings"]["epochs"]) == ("ur5e", 3, 12.0, 3)
    # the kinematic reference lacks only gravity (Eq. 11): whatever the networks learned in 3 epochs,
    # the analysis on the exact kinematics must name it with the recording's magnitude
    g = next(c for c in d["analyses"]["kinematics"]["causes"] if c["effect"] == "gravity")
    assert g["params"]["norm"] == pytest.approx(9.81, rel=0.05) and g["imus"] >= g["of"] // 2
    assert d["cpu_s"] > 0 and "| ur5e | 3 |" in md.read_text()
