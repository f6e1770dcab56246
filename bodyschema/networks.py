"""The paper's sensor networks (Sec. III-A, Fig. 2): one SE(3) pose network per IMU, trained together.

Each IMU ``k`` gets ``f_k(θ) -> (R_k(θ), b_k(θ))``: three sigmoid hidden layers, 3 translation outputs and
3 roll-pitch-yaw outputs turned into ``R = Rz(γ) Ry(β) Rx(α)`` (Eq. 12). All networks of a robot are one
module with an IMU axis on every weight (``torch.bmm``), so K networks cost one batched matrix product
per layer rather than a Python loop.

Loss (per IMU, each term divided by the spread of its sensor type over the robot, so metres and
radians weigh alike; see :func:`robot_scale`):

* accelerometer, Eq. 11 / Eq. 24: ``|α − Rᵀ (b̈ − g)|²`` with ``b̈ = H θ̇θ̇ + J θ̈`` (Eq. 3). ``b̈`` is the
  second derivative of ``b(θ(t))`` along the motion, taken by two nested forward-mode derivatives of
  ``s -> b(θ + s θ̇ + s²/2 θ̈)`` at ``s = 0``. With ``gravity=True`` (the default for data with gravity)
  the recording's gravity vector enters as a specific force, ``α = Rᵀ(b̈ − g)`` (the sensor reads +9.81 up at
  rest, docs/design.md, 'Recording'; the paper writes the same term with the opposite sign convention for g).
* gyro: ``|ω − vee(Rᵀ Ṙ)|²`` with ``Ṙ = J_R θ̇`` (forward mode). The paper compares rotations
  (Eq. 10/11: the trace of ``R1ᵀ R2``, R1 built from the predicted rate over a sample time, R2 from the
  measured one); to second order in the sample time ``3 − tr(R1ᵀR2) = Ts² |ω1 − ω2|² / 2``, so the
  squared rate error is the same objective without the arccos/trace numerics or a Ts to pick.
* a learned constant bias per IMU and axis for both sensors: an MPU-6050 gyro may be off by 20 °/s,
  which no pose network can produce (``vee(RᵀṘ)`` vanishes at rest).

Example
-------
>>> import torch
>>> net = SensorNetworks(n_imus=2, n_joints=3, hidden=(8, 8, 8), seed=0)
>>> R, b = net.pose(torch.zeros(5, 3))
>>> tuple(R.shape), tuple(b.shape)
((2, 5, 3, 3), (2, 5, 3))
>>> bool(torch.allclose(R[0, 0] @ R[0, 0].T, torch.eye(3), atol=1e-6))
True
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from bodyschema.network_options import NetworkOptions, network_options
from bodyschema.network_weights import NetworkWeights
from bodyschema.threads import set_torch_threads
from bodyschema.training import Schedule, epoch_schedule, train_epochs, warm_plateau

__all__ = [
    "NetworkOptions",  # re-exported: how these networks train
    "NetworkWeights",  # re-exported: the weights of these networks
    "SensorNetworks",
    "batched_layers",
    "mean_pose_gravity",
    "robot_scale",
    "rpy_to_matrix",
    "train_sensor_networks",
]

log = logging.getLogger(__name__)


def rpy_to_matrix(rpy: torch.Tensor) -> torch.Tensor:
    """Eq. 12: ``Rz(γ) Ry(β) Rx(α)`` for ``rpy = (α, β, γ)`` on the last axis -> (..., 3, 3)."""
    a, b, g = rpy.unbind(-1)
    ca, sa, cb, sb, cg, sg = a.cos(), a.sin(), b.cos(), b.sin(), g.cos(), g.sin()
    row0 = torch.stack([cg * cb, cg * sb * sa - sg * ca, cg * sb * ca + sg * sa], -1)
    row1 = torch.stack([sg * cb, sg * sb * sa + cg * ca, sg * sb * ca - cg * sa], -1)
    row2 = torch.stack([-sb, cb * sa, cb * ca], -1)
    return torch.stack([row0, row1, row2], -2)


def _body_rate(rpy: torch.Tensor, rpy_d: torch.Tensor) -> torch.Tensor:
    """Body rates ``vee(Rᵀ Ṙ)`` of Z-Y-X Euler angles ``rpy`` changing at ``rpy_d`` (broadcast), in
    closed form for ``R = Rz(γ) Ry(β) Rx(α)`` (Eq. 12)."""
    a, bta = rpy[..., 0], rpy[..., 1]
    da, db, dg = rpy_d.unbind(-1)
    sa, ca, sb, cb = a.sin(), a.cos(), bta.sin(), bta.cos()
    return torch.stack([da - sb * dg, ca * db + sa * cb * dg, -sa * db + ca * cb * dg], -1)


def batched_layers(
    n_models: int, sizes: Sequence[int], seed: int
) -> tuple[nn.ParameterList, nn.ParameterList]:
    """Weights ``(n_models, fan_in, fan_out)`` and biases ``(n_models, 1, fan_out)`` of ``n_models``
    independent MLPs with layer ``sizes``: one batched product per layer evaluates all of them.
    Weights are uniform in ±1/sqrt(fan_in) (PyTorch's Linear default), biases zero."""
    gen = torch.Generator().manual_seed(int(seed))
    weights, biases = nn.ParameterList(), nn.ParameterList()
    for fan_in, fan_out in itertools.pairwise(sizes):
        bound = 1.0 / math.sqrt(fan_in)
        weights.append(nn.Parameter((torch.rand(n_models, fan_in, fan_out, generator=gen) * 2 - 1) * bound))
        biases.append(nn.Parameter(torch.zeros(n_models, 1, fan_out)))
    return weights, biases


class SensorNetworks(nn.Module):
    """K pose networks ``θ -> (R, b)`` with batched weights (IMU axis first on every parameter)."""

    def __init__(self, n_imus: int, n_joints: int, hidden: Sequence[int] = (64, 64, 64), seed: int = 0):
        super().__init__()
        self.weights, self.biases = batched_layers(n_imus, [n_joints, *hidden, 6], seed)
        self.gyro_bias = nn.Parameter(torch.zeros(n_imus, 1, 3))
        # gravity direction in each network's own world frame (the frame is arbitrary, Prop. 1)
        self.gravity_dir = nn.Parameter(torch.tensor([0.0, 0.0, -1.0]).repeat(n_imus, 1, 1))
        self.acc_bias = nn.Parameter(torch.zeros(n_imus, 1, 3))
        self.n_imus = n_imus
        self.n_joints = n_joints
        #: True when training began from an earlier training's weights (:class:`NetworkWeights`)
        self.warm = False

    def set_input_scaling(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        """Standardize joint angles inside the model (sigmoid layers train badly on raw radians)."""
        self.in_mean = mean.reshape(1, -1).to(torch.float32)
        self.in_std = std.reshape(1, -1).clamp_min(1e-3).to(torch.float32)

    in_mean: torch.Tensor | None = None
    in_std: torch.Tensor | None = None

    def _scale(self, theta: torch.Tensor) -> torch.Tensor:
        if self.in_mean is None or self.in_std is None:
            return theta
        return (theta - self.in_mean) / self.in_std

    def raw(self, theta: torch.Tensor) -> torch.Tensor:
        """Network outputs (K, B, 6) for joint angles ``theta`` (B, N)."""
        x = self._scale(theta).expand(self.n_imus, *theta.shape[-2:])
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = torch.baddbmm(b, x, w)
            if i < last:
                x = torch.sigmoid(x)
        return x

    def pose(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(R (K, B, 3, 3), b (K, B, 3))`` — the sensor pose in the (unknown) world frame."""
        out = self.raw(theta)
        return rpy_to_matrix(out[..., 3:]), out[..., :3]

    def pose_jacobian_norms(self, theta: torch.Tensor) -> torch.Tensor:
        """Eq. 14 at each sample: (K, S, 4, N) column norms of every IMU network's pose Jacobian.

        The same numbers as one ``torch.func.jvp`` of :meth:`pose` per joint (what
        :func:`bodyschema.dependency.invariant_jacobian` does for any pose model), in one
        forward-mode pass: each layer carries the value and the N joint tangents stacked into one
        batched product, so N passes of small kernels become one pass of larger ones, which is what
        costs on a CPU (a warm retrain reads the Jacobian after every epoch). The rotation part needs
        no derivative of Eq. 12: for ``Ṙ = R [ω]×`` column i of Ṙ is ``R (ω × e_i)``, whose norm is
        that of ω's two other components, ω from the roll-pitch-yaw rates (:func:`_body_rate`, as
        :meth:`predict` takes it).
        """
        K, (S, N) = self.n_imus, theta.shape
        inv = torch.ones(N) if self.in_std is None else 1.0 / self.in_std.reshape(-1)
        with torch.no_grad():
            y = self._scale(theta).expand(K, S, N)
            # d (first layer's input) / d θ_j is the constant 1/std_j e_j: its tangent is a row of w
            tangent = (self.weights[0] * inv[None, :, None]).unsqueeze(2)  # (K, N, 1, H)
            last = len(self.weights) - 1
            for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
                z0 = torch.baddbmm(b, y, w)
                if i > 0:
                    tangent = torch.bmm(tangent.reshape(K, N * S, -1), w).reshape(K, N, S, -1)
                if i == last:
                    break
                y = torch.sigmoid(z0)
                tangent = (y * (1 - y)).unsqueeze(1) * tangent
            rpy = z0[..., 3:].unsqueeze(1)  # (K, 1, S, 3)
            d = tangent  # (K, N, S, 6): d output / d θ_j
            omega = _body_rate(rpy, d[..., 3:])  # (K, N, S, 3)
            s0, s1, s2 = (omega**2).unbind(-1)
            rot = torch.stack([s1 + s2, s0 + s2, s0 + s1], -1).sqrt()  # |ω × e_i|: ω without component i
            cols = torch.cat([rot, torch.linalg.vector_norm(d[..., :3], dim=-1, keepdim=True)], -1)
        return cols.permute(0, 2, 3, 1).contiguous()  # (K, S, 4, N)

    def _along(
        self, theta: torch.Tensor, theta_d: torch.Tensor, theta_dd: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Outputs and their first and second time derivatives along the motion, (K, B, 6) each.

        Forward-mode by hand (value, first and second derivative through every layer, stacked into
        one batched product per layer): the same numbers as nested ``torch.func.jvp``, at a fraction
        of the kernel launches, which is what dominates on a CPU.
        """
        K, B = self.n_imus, theta.shape[0]
        inv = 1.0 if self.in_std is None else 1.0 / self.in_std
        x = torch.cat([self._scale(theta), theta_d * inv, theta_dd * inv], 0).expand(K, 3 * B, -1)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            z = torch.bmm(x, w)
            z0, z1, z2 = z[:, :B] + b, z[:, B : 2 * B], z[:, 2 * B :]
            if i < last:
                y = torch.sigmoid(z0)
                d1 = y * (1 - y)
                d2 = d1 * (1 - 2 * y)
                x = torch.cat([y, d1 * z1, d2 * z1 * z1 + d1 * z2], 1)
            else:
                return z0, z1, z2
        raise AssertionError("unreachable")

    def predict(
        self, theta: torch.Tensor, theta_d: torch.Tensor, theta_dd: torch.Tensor, gravity: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Predicted gyro and accelerometer readings (K, B, 3) from θ, θ̇, θ̈ (B, N)."""
        out, out_d, out_dd = self._along(theta, theta_d, theta_dd)
        rpy, rpy_d = out[..., 3:], out_d[..., 3:]
        R = rpy_to_matrix(rpy)
        omega = _body_rate(rpy, rpy_d)
        b_dd = out_dd[..., :3]
        if gravity is not None:
            g_dir = self.gravity_dir / torch.linalg.vector_norm(self.gravity_dir, dim=-1, keepdim=True)
            b_dd = b_dd - torch.linalg.vector_norm(gravity) * g_dir
        acc = (R.transpose(-1, -2) @ b_dd.unsqueeze(-1)).squeeze(-1)
        return omega + self.gyro_bias, acc + self.acc_bias


class _Watched:
    """A schedule whose epochs are also shown to ``watch(epoch, loss)``, which may stop training."""

    def __init__(self, inner: Schedule, watch: Callable[[int, float], bool]) -> None:
        self._inner, self._watch = inner, watch

    def after_step(self, epoch: int) -> None:
        self._inner.after_step(epoch)

    def after_epoch(self, epoch: int, loss: float) -> bool:
        stop = self._inner.after_epoch(epoch, loss)
        return self._watch(epoch, loss) or stop


def robot_scale(meas: torch.Tensor, floor: float) -> torch.Tensor:
    """One spread for a sensor type over the whole robot: the median over IMUs of each IMU's spread.

    Each loss term is divided by its sensor's spread so that metres and radians weigh alike. One
    IMU's own spread is the wrong unit: on a link that turns about the vertical near its axis the
    accelerometer barely changes, so a per-IMU scale magnifies its tiny residuals (a few mg) a
    hundredfold. Training then keeps that IMU's pose constant to fit them (the networks of such
    first-link IMUs came out independent of every joint), or uses other joints' angles as proxies.
    """
    per_imu = meas.std(dim=1).mean(-1)  # (K,)
    return per_imu.median().clamp_min(floor)


def mean_pose_gravity(acc: torch.Tensor) -> torch.Tensor:
    """Each network's starting gravity direction (K, 1, 3): the one that puts the IMU's mean pose at
    roll = pitch = yaw = 0.

    The world frame of each network is arbitrary (Prop. 1) except through gravity. Fixed at −z, an IMU
    mounted with its x axis vertical needs pitch ±90°, where the Euler angles of Eq. 12 lose a degree
    of freedom (R's body rates depend on dα − sin β dγ only): its network then cannot follow rotations
    about one axis and drops the joint that turns it. Seen on the humanoid: every IMU that lost a true
    parent joint read gravity along x (|mean a_x| / |mean a| ≥ 0.97). At rest the accelerometer
    reads −g in the sensor frame, so −mean(a) is gravity's direction seen by the IMU in its mean pose.

    >>> acc = torch.tensor([[[9.81, 0.0, 0.0], [9.79, 0.1, 0.0]]])
    >>> [round(v, 3) for v in mean_pose_gravity(acc)[0, 0].tolist()]
    [-1.0, -0.005, -0.0]
    """
    mean = acc.mean(dim=1, keepdim=True)
    norm = torch.linalg.vector_norm(mean, dim=-1, keepdim=True)
    down = torch.tensor([0.0, 0.0, -1.0], dtype=acc.dtype)
    return torch.where(norm > 1e-6, -mean / norm.clamp_min(1e-6), down)


def train_sensor_networks(
    q: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    gyro: np.ndarray,
    acc: np.ndarray,
    gravity: np.ndarray | None,
    options: NetworkOptions | None = None,
    *,
    warm_start: NetworkWeights | None = None,
    on_epoch: Callable[[SensorNetworks, int, float], bool] | None = None,
    **fields: Any,
) -> tuple[SensorNetworks, list[float]]:
    """Fit one pose network per IMU on a recording's arrays; returns the model and the loss per epoch.

    ``gravity`` None trains the gravity-free form (Eq. 11) — right only for data without gravity.
    ``options`` are the training settings (:class:`~bodyschema.network_options.NetworkOptions`); any of
    its fields may also be given by name (``epochs=5``), replacing the value in ``options``.

    ``epochs`` None (the default) trains to convergence (:class:`bodyschema.training.Plateau`): a
    two-epoch warm-up to ``lr``, then the rate is cut to 0.3x whenever the epoch loss has not improved
    by ``plateau_tol`` (relative) for 3 epochs, and training stops after the third cut: the loss has
    flattened at three learning rates, the last one 1/37 of the first. ``max_epochs`` bounds it;
    ``len(history) < max_epochs`` says it converged. A count trains that many epochs on a one-cycle
    schedule (the paper's fixed budget). The loop is :func:`bodyschema.training.train_epochs`.

    Small batches: what under-fits the networks is the number of Adam steps, not the passes over the
    data. The networks of a robot are one batched model, so an epoch costs about the same CPU time at
    64 samples per step as at 512, but takes eight times the steps. Measured on the humanoid (26
    joints, 54 IMUs, 60 s, 40 epochs): the final loss falls from 0.116 at 512 to 0.017 at 64 for 14 %
    more CPU time, the weakest true dependency feature rises from 0.04 to 0.12 and the strongest false
    one falls from 0.125 to 0.065, which is what makes the extracted tree exact there.

    ``warm_start``: the weights of an earlier training of the same robot (same IMUs, joints and
    layers; otherwise it starts cold and logs why). Training to convergence then begins from them on
    :func:`bodyschema.training.warm_plateau`: no warm-up, two rate cuts instead of three. The
    networks already describe the body, so what is left is to follow the new window. ``net.warm``
    says which start was taken. ``on_epoch(net, epoch, loss)`` is called after every epoch and may
    stop training by returning True; on a warm start it is also called once before the first, with
    epoch -1 (its answer there is ignored).
    Threads follow :func:`set_torch_threads`; a bar (:func:`bodyschema.progress.progress`) is shown
    when ``progress``, and the loss is logged every 10 epochs either way.
    """
    o = network_options(options, **fields)
    set_torch_threads()
    torch.manual_seed(int(o.seed))
    T, N = q.shape
    K = gyro.shape[1]
    data = _Data.of(q, qd, qdd, gyro, acc, gravity)
    net = SensorNetworks(K, N, hidden=o.hidden, seed=o.seed)
    warm = _start(net, data, warm_start, o.hidden, o.epochs)
    per_epoch = max(1, math.ceil(T / o.batch_size))
    opt = torch.optim.Adam(net.parameters(), lr=o.lr)
    if warm:
        schedule = warm_plateau(opt, o.lr, per_epoch, o.plateau_tol)
    else:
        schedule = epoch_schedule(opt, o.lr, per_epoch, o.epochs, o.plateau_tol)
    net.warm = warm
    if warm and on_epoch is not None:
        # what the stored weights read from this window before any step (epoch -1): a watcher that
        # waits for the same answer several epochs in a row can count it (StableDependency)
        on_epoch(net, -1, math.nan)
    history = train_epochs(
        opt,
        _batch_loss(net, data, o.gyro_weight, o.input_sparsity),
        T,
        epochs=int(o.epochs) if o.epochs is not None else int(o.max_epochs),
        batch_size=o.batch_size,
        seed=o.seed,
        name="sensor networks",
        desc=f"sensor networks ({K} IMUs)",
        schedule=schedule if on_epoch is None else _Watched(schedule, lambda e, loss: on_epoch(net, e, loss)),
        show_progress=o.progress,
        logger=log,
    )
    return net, history


@dataclass(frozen=True)
class _Data:
    """A recording's arrays as the training reads them: float32 tensors, the IMUs' first."""

    th: torch.Tensor
    thd: torch.Tensor
    thdd: torch.Tensor
    w_meas: torch.Tensor  # (K, T, 3)
    a_meas: torch.Tensor  # (K, T, 3)
    g: torch.Tensor | None
    w_scale: torch.Tensor
    a_scale: torch.Tensor

    @classmethod
    def of(
        cls,
        q: np.ndarray,
        qd: np.ndarray,
        qdd: np.ndarray,
        gyro: np.ndarray,
        acc: np.ndarray,
        gravity: np.ndarray | None,
    ) -> _Data:
        f32 = torch.float32
        w_meas = torch.as_tensor(gyro, dtype=f32).transpose(0, 1)
        a_meas = torch.as_tensor(acc, dtype=f32).transpose(0, 1)
        return cls(
            th=torch.as_tensor(q, dtype=f32),
            thd=torch.as_tensor(qd, dtype=f32),
            thdd=torch.as_tensor(qdd, dtype=f32),
            w_meas=w_meas,
            a_meas=a_meas,
            g=None if gravity is None else torch.as_tensor(gravity, dtype=f32),
            w_scale=robot_scale(w_meas, 1e-3),
            a_scale=robot_scale(a_meas, 1e-2),
        )


def _start(
    net: SensorNetworks,
    data: _Data,
    warm_start: NetworkWeights | None,
    hidden: Sequence[int],
    epochs: int | None,
) -> bool:
    """Load ``warm_start`` into ``net`` when it fits and training runs to convergence (True), else start
    it from the data's means (and log why the weights given were not used)."""
    K, N = net.n_imus, net.n_joints
    warm = warm_start is not None and epochs is None and warm_start.fits(K, N, hidden)
    if warm:
        assert warm_start is not None
        warm_start.load_into(net)
        return True
    if warm_start is not None:
        log.info(
            "sensor networks: cold start, the stored weights do not fit (%s IMUs x %s joints, %s; "
            "now %d x %d, %s%s)",
            warm_start.n_imus,
            warm_start.n_joints,
            warm_start.hidden,
            K,
            N,
            tuple(hidden),
            ", fixed epochs" if epochs is not None else "",
        )
    net.set_input_scaling(data.th.mean(0), data.th.std(0))
    with torch.no_grad():  # start biases at the measured means: the gyro mean is mostly bias
        net.gyro_bias.copy_(data.w_meas.mean(dim=1, keepdim=True))
        if data.g is not None:
            net.gravity_dir.copy_(mean_pose_gravity(data.a_meas))
    return False


def _batch_loss(
    net: SensorNetworks, data: _Data, gyro_weight: float, input_sparsity: float
) -> Callable[[torch.Tensor], torch.Tensor]:
    """The loss of one batch of samples: both sensors' scaled squared errors, plus the group lasso."""
    K = data.w_meas.shape[0]

    def batch_loss(idx: torch.Tensor) -> torch.Tensor:
        w_hat, a_hat = net.predict(data.th[idx], data.thd[idx], data.thdd[idx], data.g)
        lw = (((w_hat - data.w_meas[:, idx]) / data.w_scale) ** 2).mean()
        la = (((a_hat - data.a_meas[:, idx]) / data.a_scale) ** 2).mean()
        loss = la + gyro_weight * lw
        if input_sparsity > 0:  # group lasso: one group per (IMU, joint) input of the first layer
            loss = loss + input_sparsity * torch.linalg.vector_norm(net.weights[0], dim=-1).sum() / K
        return loss

    return batch_loss
