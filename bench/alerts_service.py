"""The processes and requests of ``bodyhealth bench alerts``: the demo service, the busy loops beside
it, and the threads that poll its alerts and flood its retrain route.

Every request goes to the loopback address the service announced (the bench refuses any other), with
the headers a browser-less client of the write routes sends: JSON content type, ``X-Requested-With:
bodyhealth`` and, when a token is configured, ``Authorization: Bearer``. Every loop here ends on a stop
event, a deadline and a count, whichever comes first.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import select
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

import httpx

from bench import REPO_ROOT
from bench.alerts_report import AlertKey, update_first_seen
from service.api.timing import server_timings

#: Where :class:`Approver` hands its child (:mod:`bench.approver`) the API token: not on its command
#: line, which other users can read.
APPROVER_TOKEN_ENV = "BODYHEALTH_BENCH_TOKEN"

__all__ = ["AlertWatch", "Api", "Approver", "BusyLoops", "RetrainFlood", "Service", "timed"]

#: A busy loop: one Python process spinning on the core given as its first argument. It asks the kernel
#: for a SIGKILL when its parent (the second argument) ends, so not even a killed bench leaves it spinning.
_BUSY = """import ctypes, os, signal, sys
ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
if os.getppid() != int(sys.argv[2]):
    sys.exit(0)
os.sched_setaffinity(0, {int(sys.argv[1])})
while True:
    pass
"""


def _child_environment(token_var: str, token: str | None) -> dict[str, str]:
    """This process's environment for a child the bench starts: no variable named ``token_var*``
    but ``token_var`` itself set to ``token`` when there is one, and this checkout first on the path."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(token_var)}
    if token:
        env[token_var] = token
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO_ROOT), env.get("PYTHONPATH")]))
    return env


class BusyLoops:
    """``n`` processes each spinning ``while True: pass`` on a core of its own (round robin over the
    cores this process may use): the other work of a busy robot computer."""

    def __init__(self) -> None:
        self.cores = sorted(os.sched_getaffinity(0))
        self.procs: list[subprocess.Popen[bytes]] = []

    def start(self, n: int) -> None:
        for k in range(n):
            core = self.cores[k % len(self.cores)]
            self.procs.append(subprocess.Popen([sys.executable, "-c", _BUSY, str(core), str(os.getpid())]))

    def alive(self) -> int:
        return sum(p.poll() is None for p in self.procs)

    def stop(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
        for p in self.procs:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(10)


class Service:
    """``bodyhealth serve --demo`` on 127.0.0.1, port 0 (the port is read from its announcement), on
    ``data_dir/var/bodyhealth.db`` (where ``make run`` keeps it, under the data dir), stderr appended to
    ``data_dir/serve.err``. A new session of its own, so a forced stop reaches its children too."""

    def __init__(self, data_dir: Path, speed: float, token: str | None) -> None:
        self.data_dir = data_dir
        self.speed = speed
        self.token = token
        self.proc: subprocess.Popen[str] | None = None
        self.url = ""
        self.err = data_dir / "serve.err"

    def command(self) -> list[str]:
        db = f"sqlite:///{self.data_dir / 'var' / 'bodyhealth.db'}"
        cmd = [sys.executable, "-m", "cli", "serve", "--demo", "--host", "127.0.0.1", "--port", "0"]
        return [*cmd, "--database-url", db, *(["--speed", f"{self.speed:g}"] if self.speed != 1 else [])]

    def environment(self) -> dict[str, str]:
        """This process's environment without API tokens, with ``--token`` as the service's token; the
        code run is this checkout's."""
        return _child_environment("BODYHEALTH_API_TOKEN", self.token)

    def start(self, timeout: float) -> str:
        """Start it and return its base URL once bound; RuntimeError (with its stderr's tail) when it
        ends or announces nothing within ``timeout`` seconds."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        with self.err.open("a") as err:
            self.proc = subprocess.Popen(
                self.command(),
                cwd=self.data_dir,
                env=self.environment(),
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                start_new_session=True,
            )
        self.url = self._announced(timeout)
        threading.Thread(target=self._drain, daemon=True).start()
        return self.url

    def _announced(self, timeout: float) -> str:
        assert self.proc is not None and self.proc.stdout is not None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            ready, _, _ = select.select([self.proc.stdout], [], [], 0.5)
            line = self.proc.stdout.readline() if ready else ""
            m = re.search(r"(http://127\.0\.0\.1:\d+)/", line)
            if m:
                return m.group(1)
            if self.proc.poll() is not None:
                raise RuntimeError(f"the service ended before binding:\n{self.tail()}")
        raise RuntimeError(f"the service announced no URL within {timeout:g} s:\n{self.tail()}")

    def _drain(self) -> None:
        """Read what else it prints so a full pipe never blocks it."""
        proc = self.proc
        if proc is not None and proc.stdout is not None:
            for _ in proc.stdout:
                pass

    def tail(self, n: int = 3000) -> str:
        try:
            return self.err.read_text(errors="replace")[-n:]
        except OSError:
            return ""

    def _logged(self, msg: str, keys: tuple[str, ...], most: int) -> list[dict[str, Any]]:
        """The fields ``ts`` and ``keys`` of the service's JSON log lines whose message starts with
        ``msg``, in order, at most ``most``."""
        out: list[dict[str, Any]] = []
        for line in self.tail(n=1 << 30).splitlines():
            if f'"{msg}' not in line:
                continue
            with contextlib.suppress(ValueError):
                rec = json.loads(line)
                out.append({k: rec.get(k) for k in ("ts", *keys)})
        return out[:most]

    def write_waits(self, most: int = 200) -> list[dict[str, Any]]:
        """The service's logged waits for the store's write lock (over 100 ms each,
        :mod:`service.store.write_lock`), in order, at most ``most``: who waited, behind whom, how long;
        a slow approval shows as one whose writer is ``approve_baseline``."""
        out = self._logged("store write waited", ("writer", "waited_ms", "held_ms", "msg"), most)
        return [w | {"behind": str(w.pop("msg")).partition(" behind ")[2]} for w in out]

    def slow_holds(self, most: int = 200) -> list[dict[str, Any]]:
        """The service's logged holds of the store's write lock over 100 ms, in order, at most ``most``:
        the writer, how long it held the lock, its commits' share, its thread's and its process's CPU and
        the WAL's bytes when it committed (a commit that found the WAL past SQLite's checkpoint size ran
        a checkpoint)."""
        keys = ("writer", "held_ms", "commit_ms", "cpu_ms", "process_cpu_ms", "wal_bytes")
        return self._logged("store write held", keys, most)

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self, timeout: float) -> int | None:
        """SIGTERM and wait up to ``timeout`` s for its exit code; past that SIGKILL to its whole
        session (None returned)."""
        proc, self.proc = self.proc, None
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            pass
        finally:  # also when interrupted while waiting: nothing of it outlives the bench
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(30)
        return None


class _Listening(Protocol):
    url: str


class Api:
    """Requests to the service, wherever it listens now (a restart moves it to another port)."""

    def __init__(self, service: _Listening, token: str | None, timeout: float = 60.0) -> None:
        self.service = service
        self.auth = {"Authorization": f"Bearer {token}"} if token else {}
        self.client = httpx.Client(timeout=timeout, trust_env=False)

    def _url(self, path: str) -> str:
        url = self.service.url
        if not url.startswith("http://127.0.0.1:"):
            raise RuntimeError(f"refusing to send a request anywhere but 127.0.0.1 (service URL {url!r})")
        return url + path

    def get(self, path: str, **params: Any) -> httpx.Response:
        return self.client.get(self._url(path), params=params, headers=self.auth)

    def post(self, path: str, body: Any = None, **params: Any) -> httpx.Response:
        headers = {"Content-Type": "application/json", "X-Requested-With": "bodyhealth", **self.auth}
        content = b"" if body is None else json.dumps(body).encode()
        return self.client.post(self._url(path), params=params, headers=headers, content=content)

    def close(self) -> None:
        self.client.close()


class _Loop(threading.Thread):
    """A daemon thread calling ``step`` every ``interval`` s until stopped, past ``deadline``
    (monotonic) or after ``max_steps`` steps."""

    def __init__(self, interval: float, deadline: float, max_steps: int) -> None:
        super().__init__(daemon=True)
        self.interval = interval
        self.deadline = deadline
        self.max_steps = max_steps
        self.stop_event = threading.Event()
        self.steps = 0

    def run(self) -> None:
        next_t = time.monotonic()
        while (
            not self.stop_event.is_set() and self.steps < self.max_steps and time.monotonic() < self.deadline
        ):
            self.step()
            self.steps += 1
            next_t += self.interval
            self.stop_event.wait(max(0.0, next_t - time.monotonic()))

    def _time_left(self) -> bool:
        return time.monotonic() < self.deadline

    def step(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        self.stop_event.set()
        self.join(timeout=120)


class AlertWatch(_Loop):
    """Polls ``GET /api/v1/alerts`` (each robot's route where that one is missing) and keeps the first
    time, since ``t0``, that each (robot, kind, part) was seen in each state."""

    def __init__(self, api: Api, t0: float, interval: float, deadline: float) -> None:
        super().__init__(interval, deadline, max_steps=int((deadline - time.monotonic()) / interval) + 10)
        self.api = api
        self.t0 = t0
        self.lock = threading.Lock()
        self.seen: dict[AlertKey, dict[str, float]] = {}
        self.details: dict[AlertKey, dict[str, Any]] = {}
        self.errors = 0
        self.robots: Sequence[str] = ()
        self.per_robot = False

    def _alerts(self) -> list[dict[str, Any]]:
        if not self.per_robot:
            r = self.api.get("/api/v1/alerts", limit=10000)
            if r.status_code != 404:
                r.raise_for_status()
                return list(r.json())
            self.per_robot = True
        out: list[dict[str, Any]] = []
        for robot in self.robots:
            r = self.api.get(f"/api/v1/robots/{robot}/alerts", limit=10000)
            r.raise_for_status()
            out += r.json()
        return out

    def step(self) -> None:
        try:
            alerts = self._alerts()
        except (httpx.HTTPError, ValueError, RuntimeError):
            self.errors += 1  # a service restarting or too busy to answer: the next poll tries again
            return
        t = time.monotonic() - self.t0
        with self.lock:
            update_first_seen(self.seen, t, alerts, self.details)

    def snapshot(self) -> dict[AlertKey, dict[str, float]]:
        with self.lock:
            return {k: dict(v) for k, v in self.seen.items()}

    def details_snapshot(self) -> dict[AlertKey, dict[str, Any]]:
        """Each key's finding and note as first seen."""
        with self.lock:
            return {k: dict(v) for k, v in self.details.items()}


class RetrainFlood(_Loop):
    """``POST …/topology/retrain?method=network`` at ``rps`` requests per second, robots in turn, for at
    most ``max_requests``; counts the answers by status and keeps the ``Retry-After`` values."""

    def __init__(
        self, api: Api, robots: Sequence[str], rps: float, deadline: float, max_requests: int
    ) -> None:
        super().__init__(1.0 / rps, deadline, max_requests)
        self.api = api
        self.robots = list(robots)
        self.rps = rps
        self.statuses: Counter[str] = Counter()
        self.retry_after: list[float] = []

    def step(self) -> None:
        robot = self.robots[self.steps % len(self.robots)]
        try:
            r = self.api.post(f"/api/v1/robots/{robot}/topology/retrain", method="network")
        except httpx.HTTPError as err:
            self.statuses[type(err).__name__] += 1
            return
        self.statuses[str(r.status_code)] += 1
        with contextlib.suppress(TypeError, ValueError):
            self.retry_after.append(float(r.headers.get("Retry-After")))

    def result(self) -> dict[str, Any]:
        ra = self.retry_after
        return {
            "rps": self.rps,
            "requests": sum(self.statuses.values()),
            "statuses": dict(self.statuses),
            "retry_after": f"{min(ra):g}–{max(ra):g} s" if ra else "—",
        }


def timed(call: Callable[[], httpx.Response]) -> tuple[float, str, dict[str, float]]:
    """(seconds, status, the service's own milliseconds from its ``Server-Timing``: ``app``, and its
    store writes' ``store-wait``, ``store-held`` and ``store-commit``) of one request; the status is the
    exception's name, and the service's times empty, when there was no answer."""
    t = time.perf_counter()
    try:
        r = call()
    except httpx.HTTPError as err:
        return time.perf_counter() - t, type(err).__name__, {}
    return time.perf_counter() - t, str(r.status_code), server_timings(r.headers.get("server-timing"))


class Approver:
    """Baseline approvals from a process of their own (:mod:`bench.approver`): started and imported
    before the phase's clock starts, so its start-up is not in the spread, and killed if the bench
    stops first."""

    def __init__(self, url: str, token: str | None, timeout: float = 120.0) -> None:
        self.url, self.timeout = url, timeout
        self.env = _child_environment(APPROVER_TOKEN_ENV, token)
        self.proc: subprocess.Popen[str] | None = None

    def start(self, robots: Sequence[str], first: int, n: int, seconds: float, until: float) -> None:
        """Start it and wait until it is ready; RuntimeError when it is not within the timeout."""
        args = ["--robots", ",".join(robots), "--first", str(first), "--n", str(n)]
        args += ["--seconds", f"{seconds!r}", "--until", f"{until!r}"]
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bench.approver", self.url, *args],
            cwd=REPO_ROOT,
            env=self.env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], self.timeout)
        if not ready or self.proc.stdout.readline().strip() != "ready":
            self.kill()
            raise RuntimeError(f"the approvals' client was not ready within {self.timeout:g} s")

    def go(self) -> None:
        assert self.proc is not None and self.proc.stdin is not None
        self.proc.stdin.write("go\n")
        self.proc.stdin.flush()

    def rows(self) -> list[list[Any]]:
        """Each approval's [monotonic start, robot, ms, the service's ms, status, wall time, its store
        write's ms waiting for the lock and holding it]; waits for the last answer (the client's
        request timeout bounds it)."""
        assert self.proc is not None
        out, _ = self.proc.communicate(timeout=self.timeout)
        self.proc = None
        return list(json.loads(out.strip().splitlines()[-1])) if out.strip() else []

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(10)
        self.proc = None
