"""The epoch loop shared by the learned models: the sensor networks and the MLP baseline.

Both train the same way: Adam on mini-batches of shuffled samples, one permutation per epoch drawn
from a generator seeded by the caller, the epoch loss the sample-weighted mean of the batch losses, a
learning-rate schedule stepped per batch or per epoch, a log line every ten epochs and a progress bar
on demand. Kept in one place, the two models cannot drift apart in how they train, and a fit is
reproducible from its seed: the torch operations and the random draws happen in one fixed order.

The schedules are :class:`OneCycle` (a fixed budget of epochs, the paper's), :class:`Plateau` (train
until the loss flattens) and :class:`ConstantRate`; :func:`epoch_schedule` picks between the first two.

Example
-------
>>> import torch
>>> w = torch.nn.Parameter(torch.zeros(1))
>>> x = torch.linspace(0, 1, 32)
>>> opt = torch.optim.Adam([w], lr=0.1)
>>> hist = train_epochs(opt, lambda idx: ((w * x[idx] - 2 * x[idx]) ** 2).mean(), 32, epochs=3,
...                     batch_size=8, seed=0, name="line", desc="line")
>>> len(hist), hist[-1] < hist[0]
(3, True)
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Protocol

import torch

from bodyschema.progress import progress

__all__ = [
    "ConstantRate",
    "OneCycle",
    "Plateau",
    "Schedule",
    "epoch_schedule",
    "train_epochs",
    "warm_plateau",
]

log = logging.getLogger(__name__)


class Schedule(Protocol):
    """A learning-rate schedule as the loop drives it."""

    def after_step(self, epoch: int) -> None:
        """Called after every optimizer step of epoch ``epoch`` (0-based)."""

    def after_epoch(self, epoch: int, loss: float) -> bool:
        """Called after epoch ``epoch`` with its mean loss; True stops training (converged)."""


class ConstantRate:
    """The optimizer's own rate throughout; never stops early."""

    def after_step(self, epoch: int) -> None:
        return None

    def after_epoch(self, epoch: int, loss: float) -> bool:
        return False


class OneCycle:
    """A one-cycle schedule over a fixed budget: warm up to ``lr`` over the first 15 % of the steps,
    then anneal; stepped after every batch."""

    def __init__(self, optimizer: torch.optim.Optimizer, lr: float, steps_per_epoch: int, epochs: int):
        self._sched = torch.optim.lr_scheduler.OneCycleLR(
            optimizer, max_lr=lr, total_steps=steps_per_epoch * epochs, pct_start=0.15
        )

    def after_step(self, epoch: int) -> None:
        self._sched.step()

    def after_epoch(self, epoch: int, loss: float) -> bool:
        return False


class Plateau:
    """Train to convergence: a ``warmup_epochs`` linear warm-up to ``lr`` (from 0.1 ``lr``), then the
    rate is cut to 0.3x whenever the epoch loss has not improved by ``tol`` (relative) for 3 epochs;
    training stops after cut number ``cuts`` (the default three: the loss has flattened at three rates,
    the last 1/37 of the first).

    A warm start (networks that begin from the last training's weights) needs no warm-up: the weights
    are no random draw that a full rate would scatter. It starts at ``lr`` and stops after two cuts
    (:func:`warm_plateau`). Measured on paper-3 (robot sensing, two 30 s windows): from the first
    window's weights, the second trains 24 epochs to the cold run's loss (0.0106 against 0.0107, 49
    epochs) and gives the same dependency matrix, at half the CPU time; one cut stops at 17 epochs but
    20 % above the cold loss, a start at 0.3 ``lr`` takes 31. What usually ends a warm start sooner is
    not the loss: :class:`bodyschema.dependency.StableDependency`.
    """

    def __init__(
        self,
        optimizer: torch.optim.Optimizer,
        lr: float,
        steps_per_epoch: int,
        tol: float,
        warmup_epochs: int = 2,
        cuts: int = 3,
    ):
        warm = max(1, warmup_epochs * steps_per_epoch)
        self._optimizer = optimizer
        self._lr = lr
        self._warmup_epochs = warmup_epochs
        self._cuts = cuts
        self._warmup = (
            torch.optim.lr_scheduler.LambdaLR(optimizer, lambda k: min(1.0, 0.1 + 0.9 * k / warm))
            if warmup_epochs > 0
            else None
        )
        self._plateau = torch.optim.lr_scheduler.ReduceLROnPlateau(
            optimizer, factor=0.3, patience=3, threshold=tol, threshold_mode="rel"
        )

    def after_step(self, epoch: int) -> None:
        if self._warmup is not None and epoch < self._warmup_epochs:
            self._warmup.step()

    def after_epoch(self, epoch: int, loss: float) -> bool:
        if epoch < self._warmup_epochs:
            return False
        self._plateau.step(loss)
        return self._optimizer.param_groups[0]["lr"] < self._lr * 0.3**self._cuts * 1.001


def warm_plateau(optimizer: torch.optim.Optimizer, lr: float, steps_per_epoch: int, tol: float) -> Plateau:
    """The schedule of a warm start: ``optimizer`` runs at ``lr`` from the first step (no warm-up),
    two cuts (:class:`Plateau`)."""
    return Plateau(optimizer, lr, steps_per_epoch, tol, warmup_epochs=0, cuts=2)


def epoch_schedule(
    optimizer: torch.optim.Optimizer, lr: float, steps_per_epoch: int, epochs: int | None, plateau_tol: float
) -> Schedule:
    """:class:`OneCycle` over ``epochs`` when a count is given, else :class:`Plateau` at ``plateau_tol``."""
    if epochs is not None:
        return OneCycle(optimizer, lr, steps_per_epoch, int(epochs))
    return Plateau(optimizer, lr, steps_per_epoch, plateau_tol)


def train_epochs(
    optimizer: torch.optim.Optimizer,
    batch_loss: Callable[[torch.Tensor], torch.Tensor],
    n_samples: int,
    *,
    epochs: int,
    batch_size: int,
    seed: int,
    name: str,
    desc: str,
    schedule: Schedule | None = None,
    show_progress: bool = False,
    logger: logging.Logger | None = None,
) -> list[float]:
    """Train up to ``epochs`` epochs; returns the mean loss per epoch (shorter when it converged).

    Each epoch draws one permutation of the ``n_samples`` samples from a generator seeded with
    ``seed`` and walks it in batches of ``batch_size``: ``batch_loss(indices)`` gives the batch's loss,
    which is back-propagated and stepped by ``optimizer``, then ``schedule`` (default
    :class:`ConstantRate`) is told. ``name`` heads the log lines (every 10 epochs and the last, on
    ``logger``, default this module's); ``desc`` labels the bar shown when ``show_progress``.
    """
    schedule = schedule if schedule is not None else ConstantRate()
    logger = logger if logger is not None else log
    gen = torch.Generator().manual_seed(int(seed))
    history: list[float] = []
    bar = progress(total=epochs, desc=desc, unit="epoch", enabled=show_progress)
    for epoch in range(epochs):
        perm = torch.randperm(n_samples, generator=gen)
        total = 0.0
        for start in range(0, n_samples, batch_size):
            idx = perm[start : start + batch_size]
            loss = batch_loss(idx)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            schedule.after_step(epoch)
            total += float(loss.detach()) * len(idx)
        history.append(total / n_samples)
        bar.update(1)
        bar.set_postfix(loss=f"{history[-1]:.4f}")
        if epoch % 10 == 9 or epoch == epochs - 1:
            logger.info("%s: epoch %d/%d loss %.5f", name, epoch + 1, epochs, history[-1])
        if schedule.after_epoch(epoch, history[-1]):
            logger.info("%s: converged after %d epochs, loss %.5f", name, epoch + 1, history[-1])
            break
    bar.close()
    return history
