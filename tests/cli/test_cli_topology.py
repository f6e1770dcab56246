"""``bodyhealth topology``: JSON, text tree, plot, errors; on a recording written to disk."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bodyschema.topology import Topology
from cli.main import main
from simulators.kinematic_tree import random_robot_recording
from simulators.recording_io import save_recording


@pytest.fixture
def rec_path(tmp_path, rng):
    rec = random_robot_recording(rng, n_joints=int(rng.integers(4, 9)), seconds=10.0)
    path = tmp_path / "rec.npz"
    save_recording(rec, path)
    return rec, path


def test_json_is_the_design_topology_and_exact(rec_path, capsys):
    rec, path = rec_path
    assert main(["topology", str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    topo = Topology.from_json(data)
    assert topo.joint_parent == rec.truth_parent_map
    assert topo.imu_joint == rec.truth_imu_map
    assert data["method"] == "fast" and data["unique"] is True and data["seconds"] > 0
    keys = {f"imu:{i}" for i in rec.imu_names} | {f"joint:{j}" for j in rec.joint_names}
    assert set(data["confidence"]) == keys
    assert set(data["excitation"]) == set(rec.joint_names)


def test_text_tree_and_plot(rec_path, tmp_path, capsys):
    rec, path = rec_path
    png = tmp_path / "tree.png"
    assert main(["topology", str(path), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("base")
    for j in rec.joint_names:
        assert f"── {j}  (" in out
    assert "unique" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 10_000


def test_bad_file_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a recording")
    assert main(["topology", str(bad)]) == 1
    assert "not an .npz recording: not a readable zip archive" in capsys.readouterr().err
    np.savez(tmp_path / "empty.npz", t=np.arange(3.0))
    assert main(["topology", str(tmp_path / "empty.npz")]) == 1
    assert "missing keys" in capsys.readouterr().err


def test_unknown_method_is_refused_by_the_parser(rec_path):
    _, path = rec_path
    with pytest.raises(SystemExit):
        main(["topology", str(path), "--method", "magic"])


def test_stated_imu_filter_delay_is_taken_out_of_the_skew(tmp_path, capsys):
    """A multi-rate recording that does not state its IMU filter (a real robot's log): the skew is
    the lag unless ``--imu-delay-ms`` states the delay; a recording that states it (``extra["sensing"]``
    from the simulator) gives it itself. The ``robot`` preset: 8 ms skew, DLPF_CFG 3 (4.8 ms)."""
    import dataclasses

    from simulators.sensing import apply_sensing, resolve_sensing

    fine = random_robot_recording(np.random.default_rng(3), n_joints=5, seconds=20.0, rate=1000.0)
    sensed = apply_sensing(fine, resolve_sensing("robot"), np.random.default_rng(4))
    assert "sensing" in sensed.extra
    unstated = dataclasses.replace(sensed, extra={k: v for k, v in sensed.extra.items() if k != "sensing"})
    out = {}
    for name, rec, flags in [
        ("stated", sensed, []),
        ("unstated", unstated, []),
        ("flag", unstated, ["--imu-delay-ms", "4.8"]),
    ]:
        save_recording(rec, tmp_path / f"{name}.npz")
        assert main(["topology", str(tmp_path / f"{name}.npz"), "--json", *flags]) == 0
        out[name] = json.loads(capsys.readouterr().out)["timing"]
    lag = out["unstated"]["lag_ms"]
    assert lag == pytest.approx(8.0 + 4.8, abs=2.0)
    assert out["unstated"]["skew_ms"] == lag
    assert out["flag"]["skew_ms"] == pytest.approx(lag - 4.8, abs=1e-9)
    assert out["stated"]["skew_ms"] == pytest.approx(out["stated"]["lag_ms"] - 4.8, abs=1e-9)
