"""How the sensor networks train (:func:`bodyschema.networks.train_sensor_networks`), as one value.

The settings pass through several layers (the service's retrain job, :func:`bodyschema.estimate.
fit_topology`, the dependency extraction, the training loop); one frozen value keeps them typed and
their defaults in one place, and it pickles into a cluster task as it is.

Example
-------
>>> opts = network_options(epochs=5, seed=3)
>>> opts.epochs, opts.seed, opts.batch_size
(5, 3, 64)
>>> opts.keywords()
{'epochs': 5, 'seed': 3}
>>> network_options(NetworkOptions(hidden=[8, 8]), lr=1e-3).hidden
(8, 8)
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

__all__ = ["NETWORK_FIELDS", "NetworkOptions", "network_options", "split_network_options"]


@dataclass(frozen=True)
class NetworkOptions:
    """The training settings of the sensor networks; the defaults are the estimator's.

    ``epochs`` None trains to convergence (:class:`bodyschema.training.Plateau`), bounded by
    ``max_epochs``, with the rate cut whenever the epoch loss has not improved by ``plateau_tol``
    (relative); a count trains that many epochs on a one-cycle schedule (the paper's fixed budget).
    ``batch_size`` is small on purpose: what under-fits the networks is the number of Adam steps, not
    the passes over the data (:func:`bodyschema.networks.train_sensor_networks` has the figures).
    """

    #: widths of the hidden layers of every IMU's pose network
    hidden: tuple[int, ...] = (32, 32, 32)
    #: a fixed number of epochs; None: train until the loss flattens
    epochs: int | None = None
    #: samples per Adam step
    batch_size: int = 64
    #: peak learning rate
    lr: float = 1e-2
    #: weight of the gyro term against the accelerometer term of the loss
    gyro_weight: float = 1.0
    #: group-lasso weight on each (IMU, joint) input of the first layer (0: none)
    input_sparsity: float = 0.0
    #: seeds the initialization, the batches and the choice of Jacobian samples
    seed: int = 0
    #: show a progress bar
    progress: bool = False
    #: the most epochs a training to convergence may take
    max_epochs: int = 200
    #: the relative improvement of the epoch loss that counts as progress
    plateau_tol: float = 0.01

    def __post_init__(self) -> None:
        # a list of widths (JSON, a caller's list) is the same layers: compared and hashed as a tuple
        object.__setattr__(self, "hidden", tuple(self.hidden))

    def keywords(self) -> dict[str, Any]:
        """The fields that differ from the defaults, by name: what a keyword-taking estimator is given
        so that it sees exactly the settings a caller chose (its own defaults are the same)."""
        default = _DEFAULT
        return {f: getattr(self, f) for f in NETWORK_FIELDS if getattr(self, f) != getattr(default, f)}


#: The names of :class:`NetworkOptions`' fields.
NETWORK_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(NetworkOptions))

_DEFAULT = NetworkOptions()


def network_options(options: NetworkOptions | None = None, **overrides: Any) -> NetworkOptions:
    """``options`` (default: the defaults) with the keywords ``overrides`` replacing its fields; a name
    that is no field is refused."""
    unknown = sorted(set(overrides) - set(NETWORK_FIELDS))
    if unknown:
        raise TypeError(f"unexpected keyword argument(s) {unknown}; the settings are NetworkOptions fields")
    return replace(options or _DEFAULT, **overrides)


def split_network_options(kw: dict[str, Any], options: NetworkOptions | None = None) -> NetworkOptions:
    """Take the :class:`NetworkOptions` fields out of the keywords ``kw`` (in place) onto ``options``."""
    return network_options(options, **{k: kw.pop(k) for k in NETWORK_FIELDS if k in kw})
