"""``bodyhealth bench algebra`` on small sizes: its rows hold the counts and medians of what it measured."""

from __future__ import annotations

import argparse

from bench import algebra as bench


def test_summary_counts_yes_no_columns_and_takes_medians() -> None:
    rec = {
        "t": [0.3, 0.1, 0.2],
        "d": [4.0, 6.0, 5.0],
        "k": [5.0, 5.0, 6.0],
        "hit": [1.0, 0.0, 1.0],
        "true": [0.0, 0.0, 1.0],
        "cert": [1.0, 1.0, 1.0],
    }
    assert bench._summary(12, rec) == {
        "n": 12,
        "t": 0.2,
        "tmin": 0.1,
        "tmax": 0.3,
        "d": 5.0,
        "k": 5,
        "hit": 2,
        "true": 1,
        "cert": 3,
    }


def test_small_run_repairs_sparse_errors_within_their_number(tmp_path) -> None:
    p = argparse.ArgumentParser()
    bench.add_arguments(p)
    args = p.parse_args(["--sizes", "8", "--sparse-sizes", "8,12", "--repeats", "3", "--out", str(tmp_path)])
    md = bench.run(args).read_text()
    sparse = md.split("## Sparse errors", 1)[1]
    rows = [r.split("|")[1:-1] for r in sparse.splitlines() if r.startswith("| 8 ") or r.startswith("| 12 ")]
    assert [int(r[0]) for r in rows] == [8, 12]
    for r in rows:
        # N // 4 flips: every correction within the flips and certified minimal (the exact stage)
        assert int(r[1]) == int(r[0]) // 4
        assert r[4].strip() == "3/3" and r[5].strip() == "3/3", r
        assert float(r[3]) <= int(r[1])
    assert (tmp_path / "algebra.png").stat().st_size > 1000
