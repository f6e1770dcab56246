"""What the API may ask of the parts of the service it does not own: the monitoring worker and the
simulated farm. Declared as protocols so the API depends on these few calls only, not on the classes
behind them (:class:`service.worker.Worker`, :class:`service.ingest.farm.FarmDamage`), and so a second
implementation (a worker in another process behind a queue, a farm of real test rigs) fits in without
touching a route.

The data itself never takes this path: frames flow source -> pipeline -> store, and the API reads
what the worker wrote from the store.

>>> from service.ingest.farm import FarmDamage
>>> isinstance(FarmDamage([]), DamageControl)
True
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

from service.store import TopologyRecord

__all__ = ["DamageControl", "MonitorControl", "TrainingStatus"]


@runtime_checkable
class MonitorControl(Protocol):
    """The monitoring worker, as the API sees it."""

    @property
    def running(self) -> bool:
        """Whether the monitoring loop is alive (reported by ``/health``)."""
        ...

    @property
    def died(self) -> bool:
        """Whether the monitoring loop was started and its thread has ended: ``/readyz`` then answers
        503. A worker driven cycle by cycle (tests, offline tools) never started one."""
        ...

    def request(self, robot: str, method: str) -> None:
        """Queue an estimation of ``robot`` with ``method`` for the next cycle."""
        ...

    def approve_baseline(self, robot: str) -> TopologyRecord:
        """Make the newest learned topology the robot's baseline (operator decision); raises
        ``LookupError`` when nothing was learned yet."""
        ...


@runtime_checkable
class TrainingStatus(Protocol):
    """A worker that trains the sensor networks elsewhere (a Dask cluster) and can say why it cannot."""

    def training_fault(self) -> str | None:
        """Why retrains cannot run now, naming the cluster; None when they can."""
        ...


@runtime_checkable
class DamageControl(Protocol):
    """Whatever simulates robots in this process and can break them on request."""

    def simulates(self, robot: str) -> bool:
        """True when ``robot`` is simulated here (damage can be applied to it)."""
        ...

    def apply_damage(self, robot: str, kind: str, params: Mapping[str, Any]) -> dict[str, Any]:
        """Damage ``robot`` and return the ground-truth diff (docs/design.md, 'Diff JSON'). Raises
        ``KeyError`` for a robot not simulated here, ``ValueError``/``TypeError`` for arguments the
        damage kind cannot take."""
        ...
