"""A full disk, then a little space freed: the running service stores frames again without a restart,
and its SQLite WAL gives its room back instead of taking the freed space again.

On the small tmpfs of :class:`SmallDisk` (or, without root, SQLite's page limit): the disk is filled
while a robot streams, then only :data:`FREED` bytes are given back, less than the frames the WAL held
when the disk filled plus what streams on. Before, the WAL kept every page written since the last
checkpoint, which SQLite runs only at 16 MiB and which needs room for a second copy in the database
file: the freed space filled within seconds and writes failed for good. Retention (30 s of device time,
1.5 s of wall time at this source's rate) keeps what the store holds bounded, so every byte that stays
taken is the WAL's.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from service.ingest.pipeline import Pipeline
from service.settings import Settings
from service.store import open_store
from tests.service.faults import PRUNE, Committed, SmallDisk, TickSource
from tests.waits import wait_until

pytestmark = pytest.mark.slow

#: Bytes given back after the disk filled: the WAL held 1.7 MiB of frames at that point (measured), and
#: the source streams 0.8 MB/s, so without checkpoints this is gone again in under 3 s.
FREED = 4 * 2**20
#: Wall seconds of streaming after the space is back: 10 retentions, 10 prune intervals.
STREAM_AFTER = 6.0


def _size(path: Path) -> int:
    return path.stat().st_size if path.exists() else 0


def _free_some(disk: SmallDisk, nbytes: int) -> None:
    """Give ``nbytes`` back: shorten the ballast, or raise the page limit by as many pages."""
    if disk.mounted:
        size = disk.ballast.stat().st_size
        os.truncate(disk.ballast, max(size - nbytes, 0))
    else:
        assert disk.store is not None
        with disk.store.engine.connect() as conn:
            page = int(conn.exec_driver_sql("PRAGMA page_size").scalar())
        disk._set_limit(disk._limit[0] + nbytes // page)


def test_space_freed_after_a_full_disk_is_written_again_and_the_wal_shrinks(small_disk: SmallDisk) -> None:
    url = f"sqlite:///{small_disk.dir / 'store.db'}"
    settings = Settings(
        database_url=url, prune_interval_seconds=PRUNE, retention_seconds=10, window_seconds=5
    )
    store = open_store(url, settings=settings)
    wal = small_disk.dir / "store.db-wal"
    small_disk.attach(store)
    committed = Committed()
    pipe = Pipeline(
        store, [TickSource(period=0.05)], settings=settings, write_retry_seconds=0.5, put_timeout=0.05,
        queue_max_batches=50, on_commit=committed,
    )  # fmt: skip
    with pipe:
        wait_until(lambda: len(committed.t) >= 5, 10, "first commits")
        small_disk.fill()
        wait_until(lambda: pipe.write_health().failing, 10, "writes failing on the full disk")
        wal_full = _size(wal)
        stuck = pipe.counters()["tick"]["stored"]
        _free_some(small_disk, FREED)
        wait_until(
            lambda: pipe.counters()["tick"]["stored"] > stuck, 10, "frames stored after space came back"
        )
        t0 = time.monotonic()
        wal_peak = 0
        while time.monotonic() - t0 < STREAM_AFTER:
            wal_peak = max(wal_peak, _size(wal))
            time.sleep(0.05)
        failing = pipe.write_health().failing
        resumed = pipe.counters()["tick"]["stored"] - stuck
        wal_end = _size(wal)
    c = pipe.counters()["tick"]
    store.close()
    print(f"WAL at full {wal_full} B, peak after {wal_peak} B, end {wal_end} B; {resumed} samples after")
    # the source's rate over the streaming time, less a fifth for the commits' linger and the machine
    assert not failing and resumed > 0.8 * STREAM_AFTER * 100 / 0.05
    assert wal_end < wal_full and store.wal_truncations >= 1
    # never more than the truncation threshold plus one commit's pages (a second of frames, 1 MB)
    assert wal_peak <= store.wal_truncate_bytes + 2**20
    with open_store(url) as again:
        got = again.read_between("arm", -np.inf, np.inf)
        assert got is not None and 0 < got.n_samples <= c["stored"]
        # what is kept is the newest stored: every stamp read back was reported committed
        assert np.isin(got.t, committed.stamps()).all()


def test_the_wal_is_truncated_once_it_passes_its_threshold(tmp_path: Path) -> None:
    store = open_store(f"sqlite:///{tmp_path / 's.db'}")
    store.wal_truncate_bytes = 256 * 1024
    src = TickSource(n=500)
    sizes = []
    for _ in range(20):
        (batch,) = src._read_raw(0.0)
        store.write_many([batch])
        sizes.append(store.wal_bytes())
    store.close()
    # each batch is ~200 kB: the WAL passes the threshold every other write and is emptied there
    assert store.wal_truncations >= 5 and min(sizes) == 0
    assert max(sizes) <= store.wal_truncate_bytes + 2 * 2**20
