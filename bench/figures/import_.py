"""Figures from ``bench import`` (docs/bench/import.json): recording import rates."""

from __future__ import annotations

from bench.figures.files import BenchFiles, int_text, table_row

__all__ = ["doc"]


def doc(b: BenchFiles) -> str:
    d: dict = b.json("import.json")  # type: ignore[assignment]
    labels = {"ros1": "ROS 1 (.bag)", "sqlite3": "ROS 2 sqlite3", "mcap": "ROS 2 MCAP"}
    biggest = max(m["seconds"] for m in d["memory"])
    mem = {m["format"]: m for m in d["memory"] if m["seconds"] == biggest}
    lines = [
        f"Measured with {b.provenance('import')}, load average {b.load('import')}: a {d['seconds']:g} s "
        f"bag of {d['joints']} joints and {d['imus']} IMUs; the plain loop reads and deserializes every "
        f"message with `rosbags` and keeps nothing; the import writes the `.npz` too. Peak resident "
        f"memory while importing a {biggest:g} s bag into a file, against the bag's size and what the "
        "recording's numbers would take in memory:",
        "",
        "| format | import msgs/s | import MB/s | plain loop msgs/s | import / loop time | bag MB "
        "| peak RSS MB | arrays MB |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in d["rows"]:
        m = mem[r["format"]]
        lines.append(
            table_row(
                [
                    labels[r["format"]],
                    int_text(r["import_msgs_per_s"]),
                    f"{r['import_mb_per_s']:.1f}",
                    int_text(r["floor_msgs_per_s"]),
                    f"{r['import_over_floor']:.2f}",
                    int_text(m["bag_mb"]),
                    f"{m['rss_peak_mb']:.0f}",
                    f"{m['recording_arrays_mb']:.0f}",
                ]
            )
        )
    return "\n".join(lines)
