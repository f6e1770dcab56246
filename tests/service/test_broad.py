"""BROAD HDF5 import (sim2real.broad) and ``bodyhealth import broad``."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodyschema.recording import RecordingError
from cli.main import main
from sim2real.broad import BROAD_ATTRIBUTION, broad_data_dir, gap_runs, load_broad, session_of
from simulators.recording_io import load_recording
from tests.broad_data import BROAD_ENV, broad_dir, broad_marks, broad_trial, needs_broad

TRIAL_NAME = "07_undisturbed_fast_rotation_B"
TRIAL = broad_trial(TRIAL_NAME)


def _write_trial(path: Path, n: int = 1000, rate: float = 100.0, gaps: dict | None = None) -> dict:
    t = np.arange(n) / rate
    rv = np.stack([0.5 * np.sin(t), 0.3 * np.cos(0.7 * t), 0.2 * t], axis=1)
    quat = Rotation.from_rotvec(rv).as_quat(scalar_first=True)
    pos = np.stack([np.sin(t), np.cos(t), 1.0 + 0.1 * t], axis=1)
    q_nan, p_nan = quat.copy(), pos.copy()
    for (a, b), which in (gaps or {}).items():
        if "q" in which:
            q_nan[a:b] = np.nan
        if "p" in which:
            p_nan[a:b] = np.nan
    with h5py.File(path, "w") as f:
        f["imu_acc"] = np.tile([0.0, 0.0, 9.81], (n, 1))
        f["imu_gyr"] = np.zeros((n, 3))
        f["imu_mag"] = np.zeros((n, 3))
        f["opt_quat"] = q_nan
        f["opt_pos"] = p_nan
        f["movement"] = np.arange(n) > 100
        f.attrs["sampling_rate"] = rate
    return {"t": t, "quat": quat, "pos": pos}


def test_short_gaps_are_interpolated_long_ones_masked_ends_masked(tmp_path: Path) -> None:
    gaps = {(0, 20): "q", (300, 305): "qp", (600, 700): "p", (990, 1000): "q"}
    truth = _write_trial(tmp_path / "x_A.hdf5", gaps=gaps)
    rec = load_broad(tmp_path / "x_A.hdf5", max_gap=0.1)
    valid = rec.extra["ref_valid"]
    assert np.all(np.isfinite(rec.ref_quat)) and np.all(np.isfinite(rec.ref_pos))
    assert not valid[:20].any() and not valid[990:].any()  # gaps at the ends: guesses
    assert valid[300:305].all()  # 50 ms: interpolated and trusted
    assert not valid[600:700].any()  # 1 s: filled but masked
    assert valid[20:300].all() and valid[305:600].all() and valid[700:990].all()
    # the slerp fill of the short gap lands on the true smooth orientation
    err = Rotation.from_quat(rec.ref_quat[300:305], scalar_first=True).inv() * Rotation.from_quat(
        truth["quat"][300:305], scalar_first=True
    )
    assert np.degrees(err.magnitude()).max() < 0.01
    assert np.allclose(rec.ref_pos[300:305], truth["pos"][300:305], atol=1e-3)  # linear fill
    assert rec.extra["movement"].sum() == 899
    assert str(rec.extra["attribution"]) == BROAD_ATTRIBUTION
    assert rec.q is None and rec.imu_names == ("imu0",)
    assert np.allclose(rec.gravity, [0.0, 0.0, -9.81])


def test_malformed_files_are_refused_with_a_reason(tmp_path: Path) -> None:
    (tmp_path / "junk.hdf5").write_bytes(b"not hdf5")
    with pytest.raises(RecordingError, match="HDF5"):
        load_broad(tmp_path / "junk.hdf5")
    with h5py.File(tmp_path / "partial.hdf5", "w") as f:
        f["imu_acc"] = np.zeros((5, 3))
    with pytest.raises(RecordingError, match="missing datasets"):
        load_broad(tmp_path / "partial.hdf5")
    _write_trial(tmp_path / "norate.hdf5")
    with h5py.File(tmp_path / "norate.hdf5", "a") as f:
        del f.attrs["sampling_rate"]
    with pytest.raises(RecordingError, match="sampling_rate"):
        load_broad(tmp_path / "norate.hdf5")


def test_gap_runs_and_sessions() -> None:
    assert gap_runs(np.array([True, False, True, True])) == [(0, 1), (2, 4)]
    assert gap_runs(np.zeros(3, dtype=bool)) == []
    assert session_of("07_undisturbed_fast_rotation_B.hdf5") == "B"
    assert session_of("rec.npz") == ""


@needs_broad(TRIAL_NAME)
def test_cli_imports_a_real_trial(tmp_path: Path) -> None:
    out = tmp_path / "rec.npz"
    assert main(["import", "broad", str(TRIAL), "--out", str(out)]) == 0
    rec = load_recording(out)
    with h5py.File(TRIAL) as f:
        n = f["imu_acc"].shape[0]
        assert np.array_equal(rec.gyro[:, 0], f["imu_gyr"][()])
        assert np.array_equal(rec.extra["movement"], f["movement"][()])
        finite = np.all(np.isfinite(f["opt_quat"][()]), axis=1)
    assert rec.n_samples == n and rec.sample_rate == pytest.approx(285.714, rel=1e-4)
    # every sample with a measured reference is valid; the leading dropout (> 0.1 s) is not
    assert rec.extra["ref_valid"][finite].all()
    assert not rec.extra["ref_valid"][0]
    assert "Laidig" in str(rec.extra["attribution"])


def test_the_trials_are_found_where_the_environment_says_else_beside_the_checkout(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(BROAD_ENV, raising=False)
    repo = Path(__file__).resolve().parents[2]
    assert broad_dir() == repo.parent / "shared" / "data" / "broad"
    assert broad_data_dir() == broad_dir()  # the CLI's default and the tests' agree
    monkeypatch.setenv(BROAD_ENV, str(tmp_path))
    assert broad_dir() == tmp_path == broad_data_dir()
    assert broad_trial("x_A") == broad_trial("x_A.hdf5") == tmp_path / "x_A.hdf5"
    # an empty directory: a BROAD test skips, naming the directory, the trial and the variable
    marks = broad_marks("x_A")
    assert [m.name for m in marks] == ["broad", "skipif"]
    assert marks[1].args == (True,)
    reason = marks[1].kwargs["reason"]
    assert "x_A" in reason and str(tmp_path) in reason and BROAD_ENV in reason
    (tmp_path / "x_A.hdf5").write_bytes(b"")
    assert broad_marks("x_A")[1].args == (False,)


def test_cli_reports_a_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["import", "broad", str(tmp_path / "none.hdf5"), "--out", str(tmp_path / "r.npz")]) == 1
    assert "not a readable HDF5" in capsys.readouterr().err
    assert not (tmp_path / "r.npz").exists()
