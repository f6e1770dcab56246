"""``bodyhealth bench realism`` on a small grid: every cell is run, classified, and written out."""

from __future__ import annotations

import argparse
import json

from bench import realism


def test_small_realism_grid_is_exact_everywhere_and_written(tmp_path):
    parser = argparse.ArgumentParser()
    realism.add_arguments(parser)
    small = ["--joints", "4", "--robots", "1", "--seconds", "20", "--methods", "fast", "--catalog-seeds", "0"]
    args = parser.parse_args([*small, "--out", str(tmp_path)])
    md = realism.run(args)
    data = json.loads((tmp_path / "realism.json").read_text())
    rows = data["rows"]
    assert [r["cell"] for r in rows] == list(realism.CELLS)
    # every cell of this robot is decided and right; the timed cells find the skew within 1 ms
    assert {r["verdict"] for r in rows} == {"exact"}
    timed = [r for r in rows if r["cell"] != "ideal"]
    assert all(abs(r["skew_err_ms"]) < 1.0 for r in timed)
    assert "skew_err_ms" not in rows[0]
    s = data["summary"]["fast"]
    assert (s["exact"], s["undetermined"], s["wrong"]) == (len(rows), 0, 0)
    text = md.read_text()
    assert "| robot preset | 1/0/**0**" in text
    assert data["machine"] in text
    assert (tmp_path / "realism.png").stat().st_size > 5000
    # a cell rerun alone meets the same robot and the same sensing draws as in the run of all
    some = tmp_path / "some"
    args = parser.parse_args([*small, "--cells", "DLPF 20 Hz,robot preset", "--out", str(some)])
    realism.run(args)
    again = json.loads((some / "realism.json").read_text())
    assert "--cells 'DLPF 20 Hz,robot preset'" in again["command"]
    assert [r["cell"] for r in again["rows"]] == ["DLPF 20 Hz", "robot preset"]
    for r in again["rows"]:
        (same,) = [x for x in rows if x["cell"] == r["cell"]]
        assert (r["verdict"], r["skew_ms"]) == (same["verdict"], same["skew_ms"])
