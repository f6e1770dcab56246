"""The parts of the storage-fault tests, shared by the service and the whole-process ones: an endless
source, a disk that fills up and is given back, a PostgreSQL server of the test's own to stop and start
(the ``small_disk`` and ``pg_cluster`` fixtures of tests/service/conftest.py wrap the last two).
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sqlalchemy import event

from service.frames import FrameBatch
from service.ingest.base import Source
from service.store import Store
from tests.ports import free_port

PRUNE = 0.5  # prune interval of these tests, seconds
N_IMU = 8


class TickSource(Source):
    """An endless robot: ``n`` samples of ``N_IMU`` IMUs per read, device time running on, one read per
    ``period`` seconds (about 40 kB a batch, so a small disk fills in a moment)."""

    def __init__(self, name: str = "tick", robot: str = "arm", n: int = 100, period: float = 0.02) -> None:
        super().__init__(name)
        self.robot, self.n, self.period, self._k = robot, n, period, 0
        self._rng = np.random.default_rng(0)

    def _read_raw(self, timeout: float) -> list[FrameBatch]:
        time.sleep(self.period)
        t = (self._k * self.n + np.arange(self.n)) * 0.01
        self._k += 1
        acc = self._rng.standard_normal((self.n, N_IMU, 3))
        gyro = self._rng.standard_normal((self.n, N_IMU, 3))
        imus = tuple(f"imu{i}" for i in range(N_IMU))
        return [FrameBatch(self.robot, t, ("j1",), np.zeros((self.n, 1)), imus, acc, gyro)]


class Committed:
    """``on_commit``: every device time stamp the pipeline reported committed."""

    def __init__(self) -> None:
        self.t: list[np.ndarray] = []
        self._lock = threading.Lock()

    def __call__(self, batches: list[FrameBatch]) -> None:
        with self._lock:
            self.t.extend(b.t.copy() for b in batches)

    def stamps(self) -> np.ndarray:
        with self._lock:
            return np.concatenate(self.t) if self.t else np.zeros(0)


class SmallDisk:
    """Room for the database that can run out and be given back: a 64 MiB tmpfs filled up to
    ``headroom`` bytes by a ballast file when mounting is allowed, else ``max_page_count``."""

    def __init__(self, tmp: Path) -> None:
        self.dir = tmp / "disk"
        self.dir.mkdir()
        self.mounted = os.geteuid() == 0 and self._mount()
        self.ballast = self.dir / "ballast"
        self._limit = [2**30]
        self.store: Store | None = None

    def _mount(self) -> bool:
        r = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(self.dir)], capture_output=True
        )
        return r.returncode == 0

    def attach(self, store: Store) -> None:
        """Without a tmpfs: every new connection of ``store`` gets the current page limit."""
        self.store = store
        if not self.mounted:

            def limit(dbapi_conn: Any, _rec: Any) -> None:
                dbapi_conn.execute(f"PRAGMA max_page_count={self._limit[0]}")

            event.listen(store.engine, "connect", limit)

    def fill(self, headroom: int = 256 * 1024) -> None:
        if self.mounted:
            block = b"\0" * 65536
            with open(self.ballast, "wb") as fh:  # the store grows meanwhile: stop at the headroom or full
                try:
                    while (st := os.statvfs(self.dir)).f_bavail * st.f_frsize > headroom:
                        fh.write(block)
                        fh.flush()
                except OSError:
                    pass
        else:
            assert self.store is not None
            with self.store.engine.connect() as conn:
                pages = conn.exec_driver_sql("PRAGMA page_count").scalar()
            self._set_limit(int(pages) + 4)

    def free(self) -> None:
        if self.mounted:
            self.ballast.unlink()
        else:
            self._set_limit(2**30)

    def _set_limit(self, pages: int) -> None:
        self._limit[0] = pages
        assert self.store is not None
        self.store.engine.dispose()  # pooled connections go; new ones take the new limit

    def close(self) -> None:
        if self.mounted:
            subprocess.run(["umount", "-l", str(self.dir)], capture_output=True)


class PgCluster:
    """A PostgreSQL server of the test's own (initdb in a temp dir, a free port), to stop and start at
    will; as root it runs as the ``postgres`` user (initdb refuses root)."""

    def __init__(self) -> None:
        initdbs = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
        if not initdbs:
            pytest.skip("no initdb under /usr/lib/postgresql: cannot run a PostgreSQL server to stop")
        self.bindir = Path(initdbs[-1]).parent
        self.base = Path(tempfile.mkdtemp(prefix="bodyhealth-pgfault-"))
        self.data, self.port = self.base / "pgdata", free_port()
        self.prefix: list[str] = []
        if os.geteuid() == 0:
            import pwd

            pw = pwd.getpwnam("postgres")
            os.chown(self.base, pw.pw_uid, pw.pw_gid)
            self.prefix = ["runuser", "-u", "postgres", "--"]
        self._run("initdb", "-D", str(self.data), "-U", "postgres", "--auth=trust", "-E", "UTF8")
        self.start()
        self._run("createdb", "-h", "127.0.0.1", "-p", str(self.port), "-U", "postgres", "bodyhealth")

    @property
    def url(self) -> str:
        return f"postgresql+psycopg://postgres@127.0.0.1:{self.port}/bodyhealth"

    def _run(self, tool: str, *args: str) -> None:
        cmd = [*self.prefix, str(self.bindir / tool), *args]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, f"{tool} failed: {r.stderr[-2000:]}"

    def start(self) -> None:
        opts = f"-p {self.port} -k {self.base} -c listen_addresses=127.0.0.1 -c fsync=off"
        self._run("pg_ctl", "-D", str(self.data), "-l", str(self.base / "pg.log"), "-w", "-o", opts, "start")

    def stop(self) -> None:
        """Stop as a crash would (``immediate``): connections die mid-session."""
        self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "stop")

    def destroy(self) -> None:
        subprocess.run(
            [*self.prefix, str(self.bindir / "pg_ctl"), "-D", str(self.data), "-m", "immediate", "stop"],
            capture_output=True,
            timeout=60,
        )
        shutil.rmtree(self.base, ignore_errors=True)
