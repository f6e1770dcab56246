"""The weights of a robot's trained sensor networks as plain arrays (no torch needed to hold them).

Kept apart from :mod:`bodyschema.networks` so that what stores and ships them (the service's store, a
Dask task's result) does not import torch for it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["NetworkWeights"]


@dataclass(frozen=True)
class NetworkWeights:
    """A trained :class:`~bodyschema.networks.SensorNetworks` as plain arrays, to start the next
    training from (a warm start).

    ``arrays`` holds every parameter by its ``state_dict`` name, and the input scaling (``in_mean``,
    ``in_std``): the networks' function of the raw angles depends on it, so a warm start keeps the
    scaling it was trained with rather than the new window's. Plain numpy, so that the service can
    store it (:mod:`service.store`) and a Dask task can carry it.

    >>> from bodyschema.networks import SensorNetworks
    >>> net = SensorNetworks(n_imus=2, n_joints=3, hidden=(4, 4), seed=0)
    >>> w = NetworkWeights.from_model(net)
    >>> w.hidden, w.fits(2, 3, (4, 4)), w.fits(3, 3, (4, 4))
    ((4, 4), True, False)
    """

    n_imus: int
    n_joints: int
    hidden: tuple[int, ...]
    arrays: Mapping[str, np.ndarray]

    @classmethod
    def from_model(cls, net: Any) -> NetworkWeights:
        """The weights and input scaling of a trained ``net`` (a
        :class:`bodyschema.networks.SensorNetworks`; typed loosely, that module imports this one),
        copied."""
        arrays = {k: v.detach().cpu().numpy().copy() for k, v in net.state_dict().items()}
        if net.in_mean is not None and net.in_std is not None:
            arrays["in_mean"] = net.in_mean.numpy().copy()
            arrays["in_std"] = net.in_std.numpy().copy()
        hidden = tuple(int(w.shape[-1]) for w in net.weights[:-1])
        return cls(net.n_imus, net.n_joints, hidden, arrays)

    def fits(self, n_imus: int, n_joints: int, hidden: Sequence[int]) -> bool:
        """True when these weights are of networks of this shape (same IMUs, joints, layers)."""
        return (self.n_imus, self.n_joints, self.hidden) == (n_imus, n_joints, tuple(hidden))

    def load_into(self, net: Any) -> None:
        """Copy the weights and the input scaling into ``net`` (of the same shape)."""
        import torch

        params = {k: torch.as_tensor(v) for k, v in self.arrays.items() if k not in ("in_mean", "in_std")}
        net.load_state_dict(params)
        if "in_mean" in self.arrays:
            net.set_input_scaling(
                torch.as_tensor(self.arrays["in_mean"]), torch.as_tensor(self.arrays["in_std"])
            )
