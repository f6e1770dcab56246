"""``bodyhealth robots`` and ``bodyhealth simulate`` end to end (in process)."""

from __future__ import annotations

import json

import numpy as np

from service.cli import main
from simulators.catalog import CATALOG
from simulators.recording_io import load_recording
from simulators.robot import Robot


def test_robots_lists_the_catalog_with_counts(capsys) -> None:
    assert main(["robots", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert list(rows) == list(CATALOG)
    assert rows["paper-1"]["joints"] == 5 and rows["paper-1"]["imus"] == 60
    assert rows["ur5e"]["imus"] == 12 and rows["humanoid"]["joints"] >= 20
    assert main(["robots"]) == 0
    assert "dual-arm" in capsys.readouterr().out


def test_simulate_writes_a_recording_with_truth_from_the_model(tmp_path, capsys) -> None:
    out = tmp_path / "rec.npz"
    rc = main(
        [
            "simulate",
            "ur5e",
            "--seconds",
            "0.5",
            "--seed",
            "3",
            "--imu-model",
            "ideal",
            "--excitation",
            "sine",
            "--damage",
            "encoder_fault:joint=elbow,at=0.2",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    rec = load_recording(out)
    truth = Robot.from_catalog("ur5e").truth()
    assert rec.truth_parent_map == truth.joint_parent
    assert rec.truth_imu_map == truth.imu_joint
    assert rec.n_samples == 50 and rec.extra["excitation"].shape == (6,)
    diff = json.loads(str(rec.extra["truth_diff"]))
    assert diff["findings"][0]["kind"] == "encoder_fault" and diff["findings"][0]["joint"] == "elbow"
    assert json.loads(str(rec.extra["imu_model"]))["name"] == "ideal"
    e = rec.joint_names.index("elbow")
    assert np.ptp(rec.q[20:, e]) == 0.0
    assert "encoder_fault" in capsys.readouterr().out


def test_simulate_with_an_imu_model_file_and_bad_input(tmp_path, capsys) -> None:
    model = tmp_path / "m.json"
    model.write_text(
        json.dumps(
            {"name": "biased", "effects": [{"effect": "gyro_bias", "params": {"vector": [0.5, 0, 0]}}]}
        )
    )
    out = tmp_path / "r.npz"
    assert (
        main(
            [
                "simulate",
                "paper-1",
                "--seconds",
                "0.2",
                "--excitation",
                "hold",
                "--imu-model",
                str(model),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert np.allclose(load_recording(out).gyro[..., 0], 0.5, atol=1e-6)
    assert main(["simulate", "paper-9", "--seconds", "0.2", "--out", str(out)]) == 1
    assert main(["simulate", "paper-1", "--damage", "imu_moved:imu=imu99", "--out", str(out)]) == 1
    assert main(["simulate", "paper-1", "--imu-model", "nope.json", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "paper-9" in err and "imu99" in err and "nope.json" in err
