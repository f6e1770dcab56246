"""``bodyhealth bench load`` on a short run: the demo service under locust's mixed reads, with the table,
JSON and plot written and values that can only come from a real run."""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from bench import load as bench
from tests.bench.args import bench_args

pytestmark = [pytest.mark.slow, pytest.mark.e2e]


def _locust_bin(ms: float) -> float:
    """The value locust files a response time under: its percentiles come from these bins (whole
    milliseconds below 100 ms, tens below 1 s, ...) while its maximum is the exact time, so a p99 of
    22 ms beside a maximum of 21.95 ms is one response in the 22 ms bin, not a disorder."""
    digits = 0 if ms < 100 else -1 if ms < 1000 else -2 if ms < 10000 else -3
    return float(round(ms, digits))


def test_locust_bins_match_the_percentiles_it_reports() -> None:
    bins = [_locust_bin(ms) for ms in (21.945, 99.4, 104.9, 1260.0)]
    assert bins == [22, 99, 100, 1300]


def test_bench_load_measures_latency_while_the_farm_ingests(tmp_path: Path) -> None:
    args = bench_args(bench, *["--rps", "20", "--seconds", "6", "--warmup", "2", "--out", str(tmp_path)])
    assert bench.run(args) == tmp_path / "load.md"
    data = json.loads((tmp_path / "load.json").read_text())
    assert (tmp_path / "load.png").stat().st_size > 1000
    assert (data["target_rps"], data["target_p99_ms"]) == (200.0, 20.0)
    (row,) = data["rows"]
    assert row["offered_rps"] == 20.0 and row["failures"] == 0
    # locust paces 2 users at 10 rps each: about 120 requests in 6 s
    assert 60 <= row["requests"] <= 180 and 10.0 <= row["achieved_rps"] <= 30.0
    assert 0 < row["p50_ms"] <= row["p95_ms"] <= row["p99_ms"] <= _locust_bin(row["max_ms"])
    # the farm kept ingesting meanwhile: three robots at 100 Hz, nothing dropped
    assert row["frames_stored_per_s"] > 50 and row["frames_dropped"] == 0
    assert row["service_cpu_per_s"] > 0


def _server(timing: str | None) -> ThreadingHTTPServer:
    """A keep-alive HTTP server on a free port answering every GET with one robot, and with
    ``Server-Timing: timing`` when given."""

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def do_GET(self) -> None:
            body = b'[{"name": "r"}]'
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            if timing is not None:
                self.send_header("Server-Timing", timing)
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    srv = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv


@pytest.mark.parametrize(("timing", "own"), [("app;dur=2.5, store-wait;dur=0.0", "2.5"), (None, "nan")])
def test_the_threads_client_reads_the_services_own_time(timing: str | None, own: str) -> None:
    srv = _server(timing)
    try:
        agg = bench.read_mix(f"http://127.0.0.1:{srv.server_port}", 40.0, 2, 1.0)
    finally:
        srv.shutdown()
        srv.server_close()
    # 2 users at 20 rps each for 1 s: about 40 requests, every one answered
    assert 30 <= int(agg["Request Count"]) <= 42 and agg["Failure Count"] == "0"
    assert (agg["App 50%"], agg["App 99%"]) == (own, own)
    assert bench._finite(agg["App 99%"]) == (None if timing is None else 2.5)
    assert 0 < float(agg["50%"]) <= float(agg["99%"])
