"""The MLP regressor baseline of the paper's Sec. IV-D (Eq. 25), for comparison in the benchmark.

One independent multi-layer perceptron per IMU maps ``(θ, θ̇, θ̈)`` straight to the six readings
``(α̂, β̂)`` (accelerometer, gyro), trained on ``‖α − α̂‖ + ‖β − β̂‖`` (Eq. 25). Its dependency feature is
the Jacobian of the readings w.r.t. θ only (the paper slices the (6, 3N) Jacobian), pushed through the
same statistic / feature / δ pipeline as the sensor networks (:mod:`bodyschema.dependency`). The paper
reports that this baseline does not find the right trees; the benchmark measures it here.

As with :mod:`bodyschema.networks`, all IMUs' MLPs are one module with an IMU axis on every weight.

Example
-------
>>> import torch
>>> net = BatchedMLP(n_imus=2, n_in=9, hidden=(8, 8), seed=0)
>>> tuple(net(torch.zeros(4, 9)).shape)
(2, 4, 6)
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from bodyschema.networks import batched_layers
from bodyschema.threads import set_torch_threads
from bodyschema.training import train_epochs

__all__ = ["BatchedMLP", "mlp_jacobian", "train_mlp"]

log = logging.getLogger(__name__)


class BatchedMLP(nn.Module):
    """K independent MLPs (tanh hidden layers) evaluated as one batched product per layer."""

    def __init__(self, n_imus: int, n_in: int, hidden: Sequence[int] = (64, 64, 64), seed: int = 0):
        super().__init__()
        self.weights, self.biases = batched_layers(n_imus, [n_in, *hidden, 6], seed)
        self.n_imus = n_imus
        self.register_buffer("in_mean", torch.zeros(1, n_in))
        self.register_buffer("in_std", torch.ones(1, n_in))
        self.register_buffer("out_mean", torch.zeros(n_imus, 1, 6))
        self.register_buffer("out_std", torch.ones(n_imus, 1, 6))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Readings (K, B, 6) = (acc, gyro) for inputs (B, 3N) = (θ, θ̇, θ̈)."""
        h = ((x - self.in_mean) / self.in_std).expand(self.n_imus, *x.shape)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = torch.baddbmm(b, h, w)
            if i < last:
                h = torch.tanh(h)
        return h * self.out_std + self.out_mean


def train_mlp(
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    gyro: np.ndarray,
    acc: np.ndarray,
    hidden: Sequence[int] = (64, 64, 64),
    epochs: int = 60,
    batch_size: int = 256,
    lr: float = 3e-3,
    seed: int = 0,
    progress: bool = False,
) -> tuple[BatchedMLP, list[float]]:
    """Fit the per-IMU MLPs on Eq. 25 (readings standardized per IMU and axis); loss per epoch.

    Adam at a constant rate ``lr`` for ``epochs`` epochs (:func:`bodyschema.training.train_epochs`);
    threads follow :func:`bodyschema.threads.set_torch_threads`, a bar is shown when ``progress``.
    """
    set_torch_threads()
    torch.manual_seed(int(seed))
    f32 = torch.float32
    x = torch.as_tensor(np.concatenate([q, qd, qdd], axis=1), dtype=f32)
    y = torch.as_tensor(np.concatenate([acc, gyro], axis=2), dtype=f32).transpose(0, 1)  # (K, T, 6)
    T, K = x.shape[0], y.shape[0]
    net = BatchedMLP(K, x.shape[1], hidden=hidden, seed=seed)
    net.in_mean.copy_(x.mean(0, keepdim=True))
    net.in_std.copy_(x.std(0, keepdim=True).clamp_min(1e-6))
    net.out_mean.copy_(y.mean(1, keepdim=True))
    net.out_std.copy_(y.std(1, keepdim=True).clamp_min(1e-6))
    opt = torch.optim.Adam(net.parameters(), lr=lr)

    def batch_loss(idx: torch.Tensor) -> torch.Tensor:
        err = (net(x[idx]) - y[:, idx]) / net.out_std
        norms = torch.linalg.vector_norm(err.unflatten(-1, (2, 3)), dim=-1)  # (K, B, 2): acc, gyro
        return norms.sum(-1).mean()

    history = train_epochs(
        opt,
        batch_loss,
        T,
        epochs=epochs,
        batch_size=batch_size,
        seed=seed,
        name="MLP baseline",
        desc=f"MLP baseline ({K} IMUs)",
        show_progress=progress,
        logger=log,
    )
    return net, history


def mlp_jacobian(
    net: BatchedMLP, theta: torch.Tensor, theta_d: torch.Tensor, theta_dd: torch.Tensor
) -> torch.Tensor:
    """|∂(α̂, β̂)/∂θ_j| per reading: (K, S, 6, N), the θ slice of the (6, 3N) Jacobian (Sec. IV-D)."""
    from torch.func import jvp

    N = theta.shape[1]
    cols = []
    with torch.no_grad():
        for j in range(N):
            e = torch.zeros_like(theta)
            e[:, j] = 1.0
            x = torch.cat([theta, theta_d, theta_dd], 1)
            t = torch.cat([e, torch.zeros_like(theta_d), torch.zeros_like(theta_dd)], 1)
            _, d = jvp(net, (x,), (t,))
            cols.append(d.abs())
    return torch.stack(cols, -1)
