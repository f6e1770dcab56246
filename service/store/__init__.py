"""The windowed store: frames per robot kept for a retention window, plus topologies, baselines, alerts.

Frames arrive as :class:`~service.frames.FrameBatch` and are kept by *device* time. Consecutive
batches of one robot are coalesced into chunks (one row per chunk holding float64 blobs, see
:mod:`service.db.models`), so a 60 s window of a 72-IMU robot is a handful of rows and reads back as
arrays in milliseconds. Robots, joints and IMUs register the first time they appear; each chunk records
which IMUs it carries, so an IMU may fall silent and come back. Everything else the service keeps
(learned topologies, baselines, alerts, heartbeats) lives here too, so one object is the whole data
layer. The schema is created and upgraded by the Alembic migrations only, and only when asked:
:meth:`Store.upgrade`, :func:`open_store` (open and upgrade), ``bodyhealth db upgrade``.

:class:`Store` is one class to its callers, put together from one module per concern:

=============================== ===========================================================
:mod:`service.store.schema`     engine, sessions, settings; the schema check and ``upgrade``
:mod:`service.store.robots`     the robot registry (robots, joints, IMUs) and ``RobotInfo``
:mod:`service.store.chunks`     batches ↔ chunk rows ↔ ``Recording`` (pure numpy)
:mod:`service.store.frames`     ``write``/``write_many``, ``read_window``/``read_between``
:mod:`service.store.retention`  ``prune``
:mod:`service.store.topologies` learned topologies, baselines, ``approve_baseline``
:mod:`service.store.alerts`     alerts and their life cycle
:mod:`service.store.heartbeats` components' last sign of life
:mod:`service.store.weights`    trained network weights (warm starts)
:mod:`service.store.kinematics` geometry baselines (drift alerts)
:mod:`service.store.floating`   floating-base robots' baselines
=============================== ===========================================================

Thread-safe: one writer at a time (a lock), any number of readers. Several processes may share one
database (SQLite WAL or PostgreSQL).

Example
-------
>>> import numpy as np
>>> from service.frames import FrameBatch
>>> store = open_store("sqlite://")
>>> t = np.arange(10) * 0.01
>>> batch = FrameBatch("arm", t, ("j1",), np.zeros((10, 1)), ("imu0",), np.ones((10, 1, 3)),
...                    np.zeros((10, 1, 3)))
>>> store.write(batch)
10
>>> rec = store.read_window("arm", seconds=0.05)
>>> rec.n_samples, rec.imu_names, float(rec.t[-1])
(5, ('imu0',), 0.09)
>>> store.robot("arm").imus
['imu0']
>>> store.close()
"""

from __future__ import annotations

from typing import Any

from service.store.alerts import ALERT_STATES, AlertRecord, AlertsMixin, UnknownAlert
from service.store.chunks import build_chunks
from service.store.floating import FloatingMixin, StoredFloating
from service.store.frames import FramesMixin
from service.store.heartbeats import HeartbeatsMixin
from service.store.kinematics import KinematicsMixin, StoredKinematics
from service.store.retention import RetentionMixin
from service.store.robots import RobotInfo, RobotLimitReached, UnknownRobot
from service.store.schema import SchemaMismatch
from service.store.topologies import BASELINE_SOURCES, TopologiesMixin, TopologyRecord
from service.store.weights import StoredWeights, WeightsMixin

__all__ = [
    "ALERT_STATES",
    "BASELINE_SOURCES",
    "AlertRecord",
    "RobotInfo",
    "RobotLimitReached",
    "SchemaMismatch",
    "Store",
    "StoredFloating",
    "StoredKinematics",
    "StoredWeights",
    "TopologyRecord",
    "UnknownAlert",
    "UnknownRobot",
    "build_chunks",
    "open_store",
]


class Store(
    FramesMixin,
    RetentionMixin,
    TopologiesMixin,
    AlertsMixin,
    HeartbeatsMixin,
    WeightsMixin,
    KinematicsMixin,
    FloatingMixin,
):
    """The service's data layer on one database (SQLite file, in-memory SQLite or PostgreSQL).

    Constructing a store opens the engine and nothing more: it does not migrate. Its first use checks
    that the database is at the newest schema revision and raises :class:`SchemaMismatch` (naming
    ``bodyhealth db upgrade``) when it is not; :meth:`upgrade` migrates it, and :func:`open_store` does
    both. ``url`` defaults to the settings' ``database_url``; retention, IMU silence and chunk size come
    from the settings unless given here.
    """


def open_store(url: str | None = None, **kwargs: Any) -> Store:
    """A :class:`Store` on ``url`` migrated to the newest schema (for the service's start, tests,
    benchmarks and tools); ``kwargs`` go to :class:`Store`."""
    store = Store(url, **kwargs)
    try:
        store.upgrade()
    except BaseException:
        store.close()
        raise
    return store
