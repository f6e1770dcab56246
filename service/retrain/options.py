"""What the cluster retrains are told: how the networks train and how many may be in flight.

The settings map onto them in one place each: :meth:`TrainingOptions.from_settings` (the training
thread's priority, the IMUs' stated filter delay, over the networks' :class:`NetworkOptions` a caller
chose) and :meth:`RetrainLimits.from_settings` (admission).

>>> from service.settings import Settings
>>> s = Settings(database_url="sqlite://", imu_filter_delay_ms=4.8)
>>> o = TrainingOptions.from_settings(s, TrainingOptions(network=NetworkOptions(epochs=2)))
>>> o.network.epochs, o.imu_delay, (o.nice, o.idle) == (s.training_nice, s.training_idle)
(2, 0.0048, True)
>>> TrainingOptions.from_settings(s.model_copy(update={"dask_scheduler": "tcp://h:8786"})).nice
0
"""

from __future__ import annotations

from dataclasses import InitVar, dataclass, field, replace

from bodyschema.network_options import NetworkOptions
from service.settings import Settings

__all__ = ["NetworkOptions", "RetrainLimits", "TrainingOptions"]


@dataclass(frozen=True)
class TrainingOptions:
    """How the retrains train on the cluster.

    ``seed`` is a shorthand for ``network``'s seed (it replaces it when given).
    """

    #: how the sensor networks train (default: to convergence)
    network: NetworkOptions = field(default_factory=NetworkOptions)
    #: the IMUs' stated filter delay, s (:func:`bodyschema.estimate.fit_topology`; None: not stated)
    imu_delay: float | None = None
    #: start the sensor networks from the robot's stored weights (:mod:`service.store.weights`)
    warm_start: bool = True
    #: nice value of the training thread (:func:`service.retrain.task.lower_priority`; 0: as it is)
    nice: int = 0
    #: the training thread in Linux's idle scheduling class (:func:`service.retrain.task.lower_priority`)
    idle: bool = False
    #: the networks' tree tested against its rivals on held-out data (None: as
    #: ``Settings.network_heldout_check`` says)
    heldout_check: bool | None = None
    seed: InitVar[int | None] = None

    def __post_init__(self, seed: int | None) -> None:
        if seed is not None:
            object.__setattr__(self, "network", replace(self.network, seed=seed))

    @classmethod
    def from_settings(cls, settings: Settings, base: TrainingOptions | None = None) -> TrainingOptions:
        """``base`` (default: the defaults) as the service runs it under ``settings``: the embedded
        cluster's retrains yield the CPU to the API and ingest (an external one is left be), and the
        IMUs' stated filter delay applies unless ``base`` states one."""
        base = base or cls()
        embedded = not settings.dask_scheduler
        return replace(
            base,
            nice=settings.training_nice if embedded else 0,
            idle=settings.training_idle and embedded,
            imu_delay=base.imu_delay if base.imu_delay is not None else settings.imu_filter_delay,
            heldout_check=(
                base.heldout_check if base.heldout_check is not None else settings.network_heldout_check
            ),
        )


@dataclass(frozen=True)
class RetrainLimits:
    """Admission control of the cluster retrains (:mod:`service.retrain.queue`).

    ``max_queued``: most retrains in flight (None: twice the cluster's worker threads, so each thread
    has one training and one ready behind it and never idles between two worker cycles; more in flight
    would only age their windows). ``max_wall_seconds``: the longest one retrain is expected to take,
    wall time; it bounds how long a window stays pinned (:meth:`pin_seconds`).
    """

    max_queued: int | None = None
    max_wall_seconds: float = 900.0

    def __post_init__(self) -> None:
        if self.max_queued is not None and self.max_queued < 1:
            raise ValueError(f"max_queued must be at least 1, got {self.max_queued}")
        if not self.max_wall_seconds > 0:
            raise ValueError(f"max_wall_seconds must be positive, got {self.max_wall_seconds}")

    @classmethod
    def from_settings(cls, settings: Settings) -> RetrainLimits:
        return cls(
            max_queued=settings.max_retrains_queued, max_wall_seconds=settings.retrain_max_wall_seconds
        )

    def capacity(self, threads: int) -> int:
        """Retrains in flight at most on a cluster of ``threads`` worker threads.

        >>> RetrainLimits().capacity(3), RetrainLimits(max_queued=5).capacity(3)
        (6, 5)
        """
        return self.max_queued if self.max_queued is not None else 2 * max(1, threads)

    def pin_seconds(self, capacity: int) -> float:
        """How long a submitted job's window stays pinned at most (:mod:`service.retrain.queue`, window
        pins).

        >>> RetrainLimits(max_wall_seconds=100.0).pin_seconds(4)
        500.0
        """
        return (capacity + 1) * self.max_wall_seconds
