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
    assert "not a readable .npz recording" in capsys.readouterr().err
    np.savez(tmp_path / "empty.npz", t=np.arange(3.0))
    assert main(["topology", str(tmp_path / "empty.npz")]) == 1
    assert "missing keys" in capsys.readouterr().err


def test_unknown_method_is_refused_by_the_parser(rec_path):
    _, path = rec_path
    with pytest.raises(SystemExit):
        main(["topology", str(path), "--method", "magic"])
