"""The command line as other programs use it: every ``--help`` works, every ``--json`` is pure JSON on
stdout, and ``diff`` answers undetermined (never "no change") when several bodies fit the data.

The commands run as real subprocesses (``python -m cli``), so anything a solver writes to the
process's standard output from C would end up in the parsed text.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest

from bodyschema.recording import Recording
from cli.commands.diff import EXIT_UNDETERMINED
from cli.main import build_parser
from simulators import simulate
from simulators.recording_io import save_recording


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cli", *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def _subcommand_paths(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = [prefix]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.extend(_subcommand_paths(sub, (*prefix, name)))
    return out


PATHS = _subcommand_paths(build_parser())


def test_the_command_tree_is_what_users_are_told() -> None:
    tops = {p[0] for p in PATHS if p}
    assert {"robots", "simulate", "topology", "diff", "serve", "import", "sim2real", "bench"} <= tops
    assert ("bench", "algebra") in PATHS and ("bench", "all") in PATHS


@pytest.mark.parametrize("path", PATHS, ids=lambda p: " ".join(p) or "bodyhealth")
def test_every_help_prints_its_usage(path: tuple[str, ...], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args([*path, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: bodyhealth {' '.join(path)}".rstrip())
    assert "-h, --help" in out


def test_bench_help_as_a_process(tmp_path: Path) -> None:
    # a '%' in a benchmark's summary once crashed argparse's help formatting
    res = _cli("bench", "--help", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "algebra" in res.stdout and "10 % of" not in res.stderr


def _drop_link_imus(rec: Recording, joint: str) -> Recording:
    """The recording without the IMUs riding ``joint``'s link: an uninstrumented link (two trees fit)."""
    assert rec.truth_imu_joint is not None
    keep = [i for i, j in enumerate(rec.truth_imu_joint) if j != joint]
    return dataclasses.replace(
        rec,
        imu_names=tuple(rec.imu_names[i] for i in keep),
        acc=rec.acc[:, keep],
        gyro=rec.gyro[:, keep],
        truth_imu_joint=tuple(rec.truth_imu_joint[i] for i in keep),
    )


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("recs")
    rec = simulate("ur5e", seconds=12.0, seed=1)
    paths = {"full": d / "full.npz", "no_elbow_imus": d / "no_elbow_imus.npz"}
    save_recording(rec, paths["full"])
    save_recording(_drop_link_imus(rec, "elbow"), paths["no_elbow_imus"])
    return paths


@pytest.mark.slow
@pytest.mark.parametrize("method", ["fast", "network", "network-paper", "mlp"])
def test_topology_json_is_pure_json(method: str, recordings: dict[str, Path], tmp_path: Path) -> None:
    res = _cli(
        "topology", str(recordings["full"]), "--json", "--method", method, "--epochs", "2", cwd=tmp_path
    )
    assert res.returncode == 0, res.stderr
    topo = json.loads(res.stdout)  # the whole of stdout, nothing before or after
    assert topo["method"] == method
    assert set(topo["joints"]) == {"shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"}
    assert len(topo["imus"]) == 12


def test_robots_json_is_pure_json(tmp_path: Path) -> None:
    res = _cli("robots", "--json", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "ur5e" in json.dumps(json.loads(res.stdout))


def test_diff_of_a_body_that_matches_is_no_change(recordings: dict[str, Path], tmp_path: Path) -> None:
    res = _cli(
        "diff", str(recordings["full"]), str(recordings["full"]), "--json", "--exit-code", cwd=tmp_path
    )
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout) == {"changed": False, "findings": []}


def test_diff_says_undetermined_when_several_bodies_fit(recordings: dict[str, Path], tmp_path: Path) -> None:
    # no IMU on the elbow's link: the wrist can hang under the elbow or under the shoulder, so the data
    # cannot confirm the baseline; "no change" would be a claim it cannot back
    rec = str(recordings["no_elbow_imus"])
    res = _cli("diff", rec, rec, "--json", "--exit-code", cwd=tmp_path)
    assert res.returncode == EXIT_UNDETERMINED, res.stderr
    out = json.loads(res.stdout)
    assert out["changed"] is None and out["findings"] == []
    assert out["reasons"][0].startswith("2 trees fit the data; they differ in joint")
    assert "elbow" in out["reasons"][1]
    text = _cli("diff", rec, rec, cwd=tmp_path).stdout
    assert "undetermined: 2 trees fit the data" in text and "no change" not in text
