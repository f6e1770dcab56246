"""``bodyhealth robots`` and ``bodyhealth simulate`` end to end (in process)."""

from __future__ import annotations

import json

import numpy as np

from cli.main import main
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
            "--sensing",
            "ideal",
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
                "--sensing",
                "ideal",
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


def test_simulate_defaults_to_the_robot_sensing_preset(tmp_path, capsys) -> None:
    """What a robot logs, not what a simulator hands out: position-only 14-bit encoders at 250 Hz on
    their own stamps, 100 Hz IMUs, and the topology command finds the 8 ms skew in it."""
    out = tmp_path / "rec.npz"
    assert main(["simulate", "ur5e", "--seconds", "20", "--seed", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    rec = load_recording(out)
    assert f"encoders {rec.t_q.shape[0]} samples at 250 Hz" in printed
    # 0.5 % of the 5001 encoder and 2001 IMU samples dropped, first and last kept
    assert 4940 <= rec.t_q.shape[0] < 5001 and 1970 <= rec.n_samples < 2001
    assert rec.is_multirate and rec.qd is None
    assert round(rec.sample_rate) == 100 and round(rec.encoder_rate) == 250
    lsb = 2 * np.pi / 2**14
    assert np.allclose(rec.q / lsb, np.round(rec.q / lsb), atol=1e-6)
    assert main(["topology", str(out), "--json"]) == 0
    topo = json.loads(capsys.readouterr().out)
    assert topo["unique"] is True
    assert {j: v["parent"] for j, v in topo["joints"].items()} == rec.truth_parent_map
    assert abs(topo["timing"]["skew_ms"] - (8.0 + 0.03 * topo["timing"]["at_s"])) < 1.0
    assert main(["topology", str(out)]) == 0
    assert "IMU-to-encoder skew" in capsys.readouterr().out
