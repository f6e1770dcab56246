"""``bodyhealth bench import`` on tiny bags: it writes its table, JSON and plot with consistent numbers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import import_ as bench
from cli.main import build_parser
from tests.bench.args import bench_args


@pytest.mark.slow
def test_bench_import_writes_results(tmp_path: Path) -> None:
    args = bench_args(
        bench,
        *[
            "--joints",
            "2",
            "--imus",
            "2",
            "--seconds",
            "2",
            "--sizes",
            "2",
            "--repeat",
            "1",
            "--out",
            str(tmp_path),
        ],
    )
    md = bench.run(args)
    data = json.loads((tmp_path / "import.json").read_text())
    assert md == tmp_path / "import.md" and (tmp_path / "import.png").stat().st_size > 1000
    assert [r["format"] for r in data["rows"]] == ["ros1", "sqlite3", "mcap"]
    for r in data["rows"]:
        # 2 s of 2 IMUs at 100 Hz and encoders at 250 Hz: 400 + 500 messages, read by both loops
        assert r["messages"] == 900
        assert r["import_msgs_per_s"] > 0 and r["floor_msgs_per_s"] > 0 and r["bag_mb"] > 0
        # (tiny bags: the ratio itself is noise here; the real bench reads seconds of messages)
        assert r["import_over_floor"] > 0
    assert [(m["format"], m["seconds"]) for m in data["memory"]] == [
        (f, 2.0) for f in ("ros1", "sqlite3", "mcap")
    ]
    for m in data["memory"]:
        assert m["messages"] == 900 and m["recording_arrays_mb"] > 0
        assert m["rss_peak_mb"] == pytest.approx(m["rss_before_mb"] + m["rss_growth_mb"], abs=0.11)
        assert m["rss_growth_mb"] >= 0 and m["import_s"] >= 0
    assert "| ROS 2 MCAP |" in md.read_text()


def test_bench_import_is_the_import_command() -> None:
    args = build_parser().parse_args(["bench", "import", "--seconds", "5"])
    assert args.seconds == 5.0 and args.bench == "import"
