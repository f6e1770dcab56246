"""Retention: the store keeps a window of frames per robot, not a history.

The worker only ever reads the latest ``window_seconds``; everything older than ``retention_seconds``
of device time is dropped by :meth:`RetentionMixin.prune`, which the ingest writer calls every
``prune_interval_seconds``. Pruning works per robot against that robot's own last frame, because robots
run on clocks of their own, and drops whole chunks, so it is one indexed DELETE per robot rather than a
rewrite of blobs. Registrations, baselines and alerts are never pruned; repeated topologies are thinned as
they are stored (:mod:`service.store.topologies`).

A window a queued retrain will read is pinned (:attr:`RetentionMixin.window_pins`,
:mod:`service.store.pins`): the chunks overlapping it stay, however old, until the pin is released or
lapses.
"""

from __future__ import annotations

from sqlalchemy import and_, delete, not_, or_, select

from service.db.models import Chunk, Robot
from service.store.pins import WindowPin, WindowPins
from service.store.schema import StoreBase

__all__ = ["PRUNE_BATCH", "RetentionMixin"]

#: Chunks dropped per transaction by :meth:`RetentionMixin.prune` (a few seconds of one robot's frames).
PRUNE_BATCH = 500


def _overlaps(pins: list[WindowPin]) -> object:
    """SQL: a chunk overlaps one of ``pins`` (same robot's ``pins``, as :meth:`read_between` reads)."""
    return or_(*(and_(Chunk.epoch == p.epoch, Chunk.t_start <= p.end, Chunk.t_end > p.start) for p in pins))


class RetentionMixin(StoreBase):
    """Dropping frames that fell out of the retention window."""

    @property
    def window_pins(self) -> WindowPins:
        """The windows :meth:`prune` keeps (module doc); one registry per store object."""
        return self.__dict__.setdefault("_window_pins", WindowPins())  # setdefault: atomic

    def prune(self, now_t: float | None = None) -> int:
        """Drop chunks that ended more than ``retention_seconds`` before ``now_t`` (device time; default
        each robot's last frame). Whole chunks go, so up to one chunk more than the retention may stay.

        Chunks of an earlier device clock epoch (:mod:`service.store.frames`) are older than anything of
        the current one, by an unknown amount: the previous epoch goes once the current one spans the
        retention (its frames are then at least that old), every epoch before it at once. A robot that
        restarts thus keeps at most two retentions of frames. Chunks overlapping a pinned window
        (:attr:`window_pins`) stay whatever their age or epoch. Returns the samples dropped.

        The chunks go in transactions of at most :data:`PRUNE_BATCH` each, the write lock let go
        between them: the previous epoch's whole retention dropped in one held the lock for 5.5 s
        on a loaded machine, and every writer (an operator's approval among them) waited behind it."""
        pinned: dict[str, list[WindowPin]] = {}
        for p in self.window_pins.active():
            pinned.setdefault(p.robot, []).append(p)
        with self._session() as s:
            robots = s.execute(
                select(Robot.id, Robot.name, Robot.last_frame_t, Robot.epoch, Robot.epoch_start_t)
            ).all()
        dropped = 0
        for rid, name, last, epoch, epoch_start in robots:
            ref = now_t if now_t is not None else last
            if ref is None:
                continue
            cutoff = ref - self.retention_seconds
            # the earliest epoch kept: the previous one until the current one spans the retention
            keep_from = epoch if epoch_start is not None and epoch_start < cutoff else epoch - 1
            aged = (Chunk.epoch == epoch) & (Chunk.t_end < cutoff)
            cond = (Chunk.robot_id == rid) & (aged | (Chunk.epoch < keep_from))
            if name in pinned:
                cond = cond & not_(_overlaps(pinned[name]))
            dropped += self._drop_chunks(cond)
        return dropped

    def _drop_chunks(self, cond: object) -> int:
        """Delete the chunks matching ``cond``, :data:`PRUNE_BATCH` per transaction; samples dropped."""
        dropped = 0
        while True:
            with self._writing() as s:
                rows = s.execute(select(Chunk.id, Chunk.n).where(cond).limit(PRUNE_BATCH)).all()
                if rows:
                    s.execute(delete(Chunk).where(Chunk.id.in_([r.id for r in rows])))
            dropped += sum(int(r.n) for r in rows)
            if len(rows) < PRUNE_BATCH:
                return dropped
