"""Trained sensor-network weights: where a robot's next training starts from (a warm start).

A network retrain from random weights costs tens of CPU seconds per robot; one that starts from the
robot's last weights needs fewer epochs (docs/service.md, "Warm starts"). The weights are kept per
robot and method, versioned (1, 2, ... per robot and method), with the names of the IMUs and joints
they were trained on and the baseline that was current then.

They are reused only while that baseline is still the current one (weights trained before any baseline
only while there is none): a new baseline is a body an operator or the worker declared the reference,
and the networks learn it from scratch. Except the weights that learned the baseline itself: when the
worker adopts a network topology as the baseline, the weights of that retrain are tied to it
(:meth:`WeightsMixin.adopt_network_weights`). Weights of other IMUs or joints (a robot that came back with
another layout) are not offered either. The newest :data:`KEEP` versions per robot and method stay.
The arrays travel as one ``.npz`` blob (numpy's own format, no pickle).

Example
-------
>>> from bodyschema.network_weights import NetworkWeights
>>> from bodyschema.networks import SensorNetworks
>>> import numpy as np
>>> from service.frames import FrameBatch
>>> from service.store import open_store
>>> store = open_store("sqlite://")
>>> store.write(FrameBatch("arm", np.arange(3.0), ("j1",), np.zeros((3, 1)), ("i1",),
...                        np.ones((3, 1, 3)), np.zeros((3, 1, 3))))
3
>>> w = NetworkWeights.from_model(SensorNetworks(n_imus=1, n_joints=1, hidden=(4,), seed=0))
>>> store.save_network_weights("arm", "network", w, ["i1"], ["j1"], baseline_id=None, wall_time=1.0)
1
>>> got = store.network_weights("arm", "network", baseline_id=None, imus=["i1"], joints=["j1"])
>>> got.version, got.weights.hidden, np.array_equal(got.weights.arrays["weights.0"], w.arrays["weights.0"])
(1, (4,), True)
>>> store.network_weights("arm", "network", baseline_id=7, imus=["i1"], joints=["j1"]) is None
True
>>> store.save_network_weights("arm", "network", w, ["i1"], ["j1"], baseline_id=None, wall_time=2.0,
...                            window_end_t=2.5)
2
>>> store.adopt_network_weights("arm", "network", window_end_t=2.5, baseline_id=7)
1
>>> store.network_weights("arm", "network", baseline_id=7).version
2
>>> store.close()
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from sqlalchemy import delete, func, insert, select, update

from bodyschema.network_weights import NetworkWeights
from service.db.models import NetworkWeightsRow
from service.store.robots import robot_id
from service.store.schema import StoreBase

__all__ = ["KEEP", "StoredWeights", "WeightsMixin", "pack_weights", "unpack_weights"]

#: Versions of weights kept per robot and method (the newest).
KEEP = 3

_SHAPE = "__shape__"


@dataclass(frozen=True)
class StoredWeights:
    """One stored version of a robot's network weights."""

    version: int
    baseline_id: int | None
    wall_time: float
    window_end_t: float | None
    imus: tuple[str, ...]
    joints: tuple[str, ...]
    weights: NetworkWeights


def pack_weights(w: NetworkWeights) -> bytes:
    """``w`` as an ``.npz`` blob (the shape header as an int array, so that loading needs no pickle).

    >>> from bodyschema.networks import SensorNetworks
    >>> w = NetworkWeights.from_model(SensorNetworks(n_imus=2, n_joints=3, hidden=(4, 5), seed=0))
    >>> back = unpack_weights(pack_weights(w))
    >>> (back.n_imus, back.n_joints, back.hidden) == (2, 3, (4, 5)), sorted(back.arrays) == sorted(w.arrays)
    (True, True)
    """
    buf = io.BytesIO()
    shape = np.asarray([w.n_imus, w.n_joints, *w.hidden], dtype=np.int64)
    np.savez(buf, **{_SHAPE: shape}, **dict(w.arrays))
    return buf.getvalue()


def unpack_weights(blob: bytes) -> NetworkWeights:
    """The :class:`NetworkWeights` of a :func:`pack_weights` blob."""
    with np.load(io.BytesIO(blob), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != _SHAPE}
        shape = [int(v) for v in z[_SHAPE]]
    return NetworkWeights(shape[0], shape[1], tuple(shape[2:]), arrays)


class WeightsMixin(StoreBase):
    """Keeping and offering the robots' trained network weights."""

    def save_network_weights(
        self,
        robot: str,
        method: str,
        weights: NetworkWeights | bytes,
        imus: Sequence[str],
        joints: Sequence[str],
        *,
        baseline_id: int | None,
        wall_time: float,
        window_end_t: float | None = None,
    ) -> int:
        """Keep a new version of ``robot``'s ``method`` weights (a blob of :func:`pack_weights` or the
        weights themselves) and drop all but the newest :data:`KEEP`; returns its version."""
        blob = weights if isinstance(weights, bytes) else pack_weights(weights)
        with self._writing() as s:
            rid = robot_id(s, robot)
            where = (NetworkWeightsRow.robot_id == rid, NetworkWeightsRow.method == method)
            version = int(
                s.scalar(select(func.coalesce(func.max(NetworkWeightsRow.version), 0)).where(*where))
            )
            version += 1
            s.execute(
                insert(NetworkWeightsRow).values(
                    robot_id=rid,
                    method=method,
                    version=version,
                    baseline_id=baseline_id,
                    wall_time=float(wall_time),
                    window_end_t=None if window_end_t is None else float(window_end_t),
                    imus=list(imus),
                    joints=list(joints),
                    data=blob,
                )
            )
            s.execute(delete(NetworkWeightsRow).where(*where, NetworkWeightsRow.version <= version - KEEP))
            return version

    def adopt_network_weights(
        self, robot: str, method: str, *, window_end_t: float | None, baseline_id: int
    ) -> int:
        """Tie the weights trained before any baseline on the window ending at ``window_end_t`` to the
        baseline ``baseline_id``: the worker made that baseline from the topology those weights
        learned, so they are that baseline's weights. Returns the rows changed."""
        if window_end_t is None:
            return 0
        with self._writing() as s:
            rid = robot_id(s, robot)
            res = s.execute(
                update(NetworkWeightsRow)
                .where(
                    NetworkWeightsRow.robot_id == rid,
                    NetworkWeightsRow.method == method,
                    NetworkWeightsRow.baseline_id.is_(None),
                    NetworkWeightsRow.window_end_t == float(window_end_t),
                )
                .values(baseline_id=baseline_id)
            )
            return int(res.rowcount or 0)

    def network_weights(
        self,
        robot: str,
        method: str,
        *,
        baseline_id: int | None,
        imus: Sequence[str] | None = None,
        joints: Sequence[str] | None = None,
    ) -> StoredWeights | None:
        """The newest weights of ``robot`` and ``method`` trained under ``baseline_id`` (None: before
        any baseline), and on these ``imus`` and ``joints`` when given; None when there are none."""
        with self._session() as s:
            rid = robot_id(s, robot)
            base = (
                NetworkWeightsRow.baseline_id.is_(None)
                if baseline_id is None
                else NetworkWeightsRow.baseline_id == baseline_id
            )
            r = s.scalar(
                select(NetworkWeightsRow)
                .where(NetworkWeightsRow.robot_id == rid, NetworkWeightsRow.method == method, base)
                .order_by(NetworkWeightsRow.version.desc())
                .limit(1)
            )
        if r is None:
            return None
        if (imus is not None and list(r.imus) != list(imus)) or (
            joints is not None and list(r.joints) != list(joints)
        ):
            return None
        return StoredWeights(
            version=int(r.version),
            baseline_id=r.baseline_id,
            wall_time=float(r.wall_time),
            window_end_t=r.window_end_t,
            imus=tuple(r.imus),
            joints=tuple(r.joints),
            weights=unpack_weights(r.data),
        )
