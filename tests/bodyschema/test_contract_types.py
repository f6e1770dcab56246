import json

import numpy as np
import pytest

from bodyschema.findings import Diff, Finding
from bodyschema.recording import Recording, RecordingError
from bodyschema.topology import Topology, TopologyError
from simulators.recording_io import load_recording, save_recording


def _rec(T=10, N=2, K=3, **kw):
    t = np.arange(T) * 0.01
    return Recording(
        t=t,
        joint_names=[f"j{i}" for i in range(N)],
        q=np.sin(t)[:, None] * np.ones(N),
        imu_names=[f"imu{i}" for i in range(K)],
        acc=np.ones((T, K, 3)),
        gyro=np.zeros((T, K, 3)),
        **kw,
    )


def test_recording_roundtrip(tmp_path):
    rec = _rec(
        truth_joint_parent=["", "j0"],
        truth_imu_joint=["j0", "j1", ""],
        extra={"excitation": np.array([0.1, 0.2])},
    )
    save_recording(rec, tmp_path / "r.npz")
    back = load_recording(tmp_path / "r.npz")
    assert back.joint_names == ("j0", "j1")
    assert back.truth_parent_map == {"j0": None, "j1": "j0"}
    assert back.truth_imu_map == {"imu0": "j0", "imu1": "j1", "imu2": None}
    np.testing.assert_array_equal(back.acc, rec.acc)
    np.testing.assert_array_equal(back.extra["excitation"], [0.1, 0.2])


def test_recording_derives_velocity():
    rec = _rec(T=200).derived()
    np.testing.assert_allclose(rec.qd[50:150, 0], np.cos(rec.t[50:150]), atol=1e-3)


@pytest.mark.parametrize(
    ("field", "value", "msg"),
    [
        ("acc", np.ones((10, 2, 3)), "acc must have shape"),
        ("q", np.full((10, 2), np.nan), "q contains NaN"),
        ("t", np.zeros(10), "duplicate stamps at index 1"),
        ("t", np.arange(10.0)[::-1].copy(), "goes backwards at index 1"),
    ],
)
def test_recording_rejects_bad_input(field, value, msg):
    kw = {
        "t": np.arange(10) * 0.01,
        "joint_names": ["a", "b"],
        "q": np.zeros((10, 2)),
        "imu_names": ["i0", "i1", "i2"],
        "acc": np.zeros((10, 3, 3)),
        "gyro": np.zeros((10, 3, 3)),
    }
    kw[field] = value
    with pytest.raises(RecordingError, match=msg):
        Recording(**kw)


def test_load_rejects_non_recording(tmp_path):
    np.savez(tmp_path / "x.npz", foo=np.zeros(3))
    with pytest.raises(RecordingError, match="missing keys"):
        load_recording(tmp_path / "x.npz")


def test_topology_json_roundtrip_and_checks():
    topo = Topology(
        joint_parent={"j1": None, "j2": "j1", "j3": "j1"},
        imu_joint={"a": "j2", "b": None},
        unique=False,
        confidence={"imu:a": 0.9},
        method="fast",
        seconds=0.5,
        undetermined=("j3",),
        candidates=(
            Topology(joint_parent={"j1": None, "j2": "j1", "j3": "j2"}, imu_joint={"a": "j2", "b": None}),
        ),
    )
    data = json.loads(json.dumps(topo.to_json()))
    assert data["joints"]["j2"] == {"parent": "j1"}
    assert data["insufficient_excitation"] == ["j3"]
    back = Topology.from_json(data)
    assert back == topo
    assert back.subtree("j1") == ["j1", "j2", "j3"]
    with pytest.raises(TopologyError, match="cycle"):
        Topology(joint_parent={"a": "b", "b": "a"}, imu_joint={})
    with pytest.raises(TopologyError, match="malformed"):
        Topology.from_json({"joints": []})


def test_diff_json():
    d = Diff(findings=(Finding(kind="insufficient_excitation", joint="j2"),))
    assert d.to_json() == {
        "changed": False,
        "findings": [{"kind": "insufficient_excitation", "joint": "j2", "confidence": 1.0}],
    }
    d2 = Diff(findings=(Finding(kind="imu_moved", imu="imu3", from_="j2", to="j4", confidence=0.97),))
    assert d2.to_json()["changed"] is True
    assert Diff.from_json(d2.to_json()) == d2
    # a decided damage on an undetermined part: the rival parts travel with it, and only when there are any
    f = Finding(kind="encoder_fault", joint="r_ankle_roll", confidence=0.6, candidates=("joint:r_hip_roll",))
    assert f.to_json()["candidates"] == ["joint:r_hip_roll"]
    assert Finding.from_json(f.to_json()) == f
    assert "candidates" not in Finding(kind="encoder_fault", joint="j1").to_json()
    with pytest.raises(ValueError, match="unknown finding kind"):
        Finding(kind="broken")
