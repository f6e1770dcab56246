"""``bodyhealth diff BASELINE.npz CURRENT.npz``: the monitoring diff offline, on simulated recordings."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cli.main import main
from simulators.recording_io import save_recording
from simulators.simulation import simulate

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("diffcli")
    out = {}
    for name, damage in (
        ("healthy", None),
        ("again", None),
        ("moved", "imu_moved:imu=imu3,to=wrist_3"),
        ("locked", "joint_locked:joint=elbow"),
    ):
        # same seed: the damaged run is the healthy body plus the damage
        rec = simulate("ur5e", 30.0, seed=7 if name != "again" else 8, damage=damage)
        out[name] = d / f"{name}.npz"
        save_recording(rec, out[name])
    return out


def test_same_body_gives_no_finding(recordings: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    assert main(["diff", str(recordings["healthy"]), str(recordings["again"]), "--json", "--exit-code"]) == 0
    assert json.loads(capsys.readouterr().out) == {"changed": False, "findings": []}


def test_moved_imu_as_json(recordings: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    rc = main(["diff", str(recordings["healthy"]), str(recordings["moved"]), "--json", "--exit-code"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and out["changed"] is True
    assert out["findings"] == [
        {
            "kind": "imu_moved",
            "imu": "imu3",
            "from": "shoulder_lift",
            "to": "wrist_3",
            "confidence": out["findings"][0]["confidence"],
        }
    ]


def test_locked_joint_as_listing(recordings: dict[str, Path], capsys: pytest.CaptureFixture) -> None:
    assert main(["diff", str(recordings["healthy"]), str(recordings["locked"])]) == 0
    text = capsys.readouterr().out
    assert "body changed: 1 finding" in text
    assert "joint_locked" in text and "joint:elbow" in text
    assert text.splitlines()[0].startswith("baseline ") and "6 joints, 12 IMUs" in text


def test_missing_file_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["diff", str(tmp_path / "nope.npz"), str(tmp_path / "nope2.npz")]) == 1
    assert "nope.npz" in capsys.readouterr().err
