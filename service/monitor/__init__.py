"""The monitoring worker's steps, each in its own module; :mod:`service.worker` runs them in its cycle.

* :mod:`~service.monitor.state`: what the worker remembers per robot and what each event forgets;
* :mod:`~service.monitor.baseline`: adopting a baseline from a streak of equal topologies;
* :mod:`~service.monitor.confirmation`: the sensor networks' word on the fast screen's findings;
* :mod:`~service.monitor.onset`: judging a displaced IMU on the data after its displacement;
* :mod:`~service.monitor.drift`: the geometry compared with the one learned on the baseline.
"""

from __future__ import annotations

__all__: list[str] = []
