"""Baseline approvals timed from a process of their own, as an operator's REST client sends them.

``bodyhealth bench alerts`` polls the alerts route and floods the retrain route from threads of its own
process; a timer in that process waits its turn for the interpreter lock behind them, and the bench
would count those turns as the service's latency. Here nothing else runs beside the timer.

The bench starts ``python -m bench.approver URL --robots a,b --n 25 --seconds 150 --until MONO``; it
prints ``ready`` once imported, starts on a line from stdin, sends approval ``k`` at ``(k + 0.5) *
seconds / n`` after that (none past the monotonic ``--until``, the bench's deadline: the clock is the
machine's, shared by both processes), and ends with one JSON line: per approval, its monotonic start,
robot, milliseconds, the service's own milliseconds (``Server-Timing``), status and the wall time of its
answer, then the milliseconds its store writes waited for the store's write lock, held it and, of
the hold, committed. The token, when there is one, comes in the environment
(``bench.alerts_service.APPROVER_TOKEN_ENV``), not on the command line.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from types import SimpleNamespace

__all__ = ["main"]


def _args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m bench.approver", description=__doc__.splitlines()[0])
    p.add_argument("url", help="the service's base URL (http://127.0.0.1:PORT)")
    p.add_argument("--robots", required=True, help="comma-separated; approved in turn")
    p.add_argument("--first", type=int, default=0, help="index into --robots of the first approval")
    p.add_argument("--n", type=int, required=True, help="approvals")
    p.add_argument("--seconds", type=float, required=True, help="spread over this many seconds")
    p.add_argument("--until", type=float, default=float("inf"), help="no approval past this monotonic time")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    from bench.alerts_service import APPROVER_TOKEN_ENV, Api, timed

    a = _args(argv)
    robots = a.robots.split(",")
    api = Api(SimpleNamespace(url=a.url), os.environ.get(APPROVER_TOKEN_ENV) or None)
    print("ready", flush=True)
    sys.stdin.readline()
    start = time.monotonic()
    rows = []
    try:
        for k in range(a.n):
            time.sleep(max(0.0, start + (k + 0.5) * a.seconds / a.n - time.monotonic()))
            if time.monotonic() >= a.until:
                break
            robot = robots[(a.first + k) % len(robots)]
            path = f"/api/v1/robots/{robot}/baseline"
            t = time.monotonic()
            took, status, own = timed(lambda path=path: api.post(path))
            store = [own.get(k) for k in ("store-wait", "store-held", "store-commit")]
            rows.append([t, robot, round(took * 1e3, 1), own.get("app"), status, time.time(), *store])
    finally:
        api.close()
        print(json.dumps(rows), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
