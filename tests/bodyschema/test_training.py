"""The shared epoch loop (bodyschema.training) and progress bar (bodyschema.progress)."""

from __future__ import annotations

import logging

import pytest
import torch

from bodyschema.progress import progress
from bodyschema.training import ConstantRate, OneCycle, Plateau, epoch_schedule, train_epochs


def _line_fit(schedule_of, epochs: int, seed: int = 0, **kw) -> tuple[list[float], torch.Tensor]:
    """Fit y = 2x from 64 samples with one weight; returns the loss history and the weight."""
    w = torch.nn.Parameter(torch.zeros(1))
    x = torch.linspace(0, 1, 64)
    opt = torch.optim.Adam([w], lr=0.05)
    hist = train_epochs(
        opt,
        lambda idx: ((w * x[idx] - 2 * x[idx]) ** 2).mean(),
        64,
        epochs=epochs,
        batch_size=16,
        seed=seed,
        name="line",
        desc="line",
        schedule=schedule_of(opt),
        **kw,
    )
    return hist, w.detach().clone()


def test_training_is_reproducible_from_its_seed() -> None:
    a, wa = _line_fit(lambda opt: ConstantRate(), 5)
    b, wb = _line_fit(lambda opt: ConstantRate(), 5)
    c, _ = _line_fit(lambda opt: ConstantRate(), 5, seed=1)
    assert a == b and torch.equal(wa, wb)
    assert a != c  # another permutation of the batches
    assert len(a) == 5 and a[-1] < a[0]


def test_schedules_budget_or_converge() -> None:
    fixed, _ = _line_fit(lambda opt: OneCycle(opt, 0.05, 4, 7), 7)
    assert len(fixed) == 7
    converged, w = _line_fit(lambda opt: Plateau(opt, 0.05, 4, 0.5), 200)
    assert 3 < len(converged) < 200  # stopped after the third cut, long before the bound
    assert isinstance(epoch_schedule(torch.optim.SGD([w], lr=0.1), 0.1, 4, None, 0.01), Plateau)
    assert isinstance(epoch_schedule(torch.optim.SGD([w], lr=0.1), 0.1, 4, 3, 0.01), OneCycle)


def test_loss_is_logged_every_ten_epochs_and_at_the_end(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.INFO, logger="bodyschema.training"):
        _line_fit(lambda opt: ConstantRate(), 12)
    lines = [r.getMessage() for r in caplog.records if r.name == "bodyschema.training"]
    assert [ln.split(" loss")[0] for ln in lines] == ["line: epoch 10/12", "line: epoch 12/12"]


def test_progress_bar_goes_to_stderr_or_nowhere(capsys: pytest.CaptureFixture[str]) -> None:
    bar = progress(total=2, desc="quiet", unit="step", enabled=False)
    bar.update(1)
    bar.set_postfix(loss="1")
    bar.close()
    assert list(progress([3, 4], desc="quiet", unit="item", enabled=False)) == [3, 4]
    with progress(total=2, desc="shown", unit="step") as shown:
        shown.update(2)
    out = capsys.readouterr()
    assert out.out == "" and "quiet" not in out.err and "shown" in out.err
