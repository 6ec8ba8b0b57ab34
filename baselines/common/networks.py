"""Networks shared by the algorithms: plain MLPs, critics and a tanh-squashed Gaussian policy."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Sequence

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # SAC reference implementation bounds


def mlp(
    in_dim: int,
    out_dim: int,
    hidden_sizes: Sequence[int] = (256, 256),
    activation: type[nn.Module] = nn.ReLU,
) -> nn.Sequential:
    """A fully connected network: ``in_dim -> hidden... -> out_dim`` with no output activation."""
    layers: list[nn.Module] = []
    last = in_dim
    for width in hidden_sizes:
        layers += [nn.Linear(last, width), activation()]
        last = width
    layers.append(nn.Linear(last, out_dim))
    return nn.Sequential(*layers)


class QNetwork(nn.Module):
    """Q(s, a): one scalar per (state, action) pair."""

    def __init__(self, obs_dim: int, act_dim: int, hidden_sizes: Sequence[int] = (256, 256)):
        super().__init__()
        self.net = mlp(obs_dim + act_dim, 1, hidden_sizes)

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs, act], dim=-1)).squeeze(-1)


class VNetwork(nn.Module):
    """V(s): one scalar per state."""

    def __init__(self, obs_dim: int, hidden_sizes: Sequence[int] = (256, 256)):
        super().__init__()
        self.net = mlp(obs_dim, 1, hidden_sizes)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs).squeeze(-1)


class TanhGaussianPolicy(nn.Module):
    """pi(a|s) = bias + scale * tanh(u), u ~ N(mu(s), sigma(s)^2), as in the SAC paper.

    ``sample`` draws through the reparameterisation f(s) = mu(s) + sigma(s) * xi and
    returns the log-density of the squashed action (change of variables through tanh and
    the affine map to the action box). Noise comes from an explicit ``torch.Generator`` so
    that exploration noise never disturbs the global RNG used to initialise weights.
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        hidden_sizes: Sequence[int] = (256, 256),
    ):
        super().__init__()
        self.trunk = mlp(obs_dim, 2 * act_dim, hidden_sizes)
        low = torch.as_tensor(action_low, dtype=torch.float32)
        high = torch.as_tensor(action_high, dtype=torch.float32)
        self.register_buffer("action_scale", (high - low) / 2.0)
        self.register_buffer("action_bias", (high + low) / 2.0)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, log_std = self.trunk(obs).chunk(2, dim=-1)
        return mean, log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)

    def deterministic(self, obs: torch.Tensor) -> torch.Tensor:
        mean, _ = self(obs)
        return self.action_bias + self.action_scale * torch.tanh(mean)

    def sample(
        self,
        obs: torch.Tensor,
        generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised action and its log-density; ``noise`` (standard normal, one row
        per observation) is drawn from ``generator`` unless given."""
        mean, log_std = self(obs)
        if noise is None:
            noise = torch.randn(
                mean.shape, generator=generator, dtype=mean.dtype, device=mean.device
            )
        return squashed_sample(mean, log_std, noise, self.action_scale, self.action_bias)


def squashed_sample(
    mean: torch.Tensor,
    log_std: torch.Tensor,
    noise: torch.Tensor,
    action_scale: torch.Tensor,
    action_bias: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """bias + scale * tanh(mean + std * noise) and its log-density (the last axis is the
    action's); shared by the one-run policy and the seed-batched one."""
    std = log_std.exp()
    pre_tanh = mean + std * noise
    gaussian_log_prob = (-0.5 * noise.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
    # log(1 - tanh(u)^2) in a form that stays finite for large |u|
    log_tanh_jacobian = 2.0 * (math.log(2.0) - pre_tanh - F.softplus(-2.0 * pre_tanh))
    log_prob = gaussian_log_prob - (log_tanh_jacobian + torch.log(action_scale)).sum(-1)
    action = action_bias + action_scale * torch.tanh(pre_tanh)
    return action, log_prob


def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """Polyak averaging: target <- (1 - tau) * target + tau * source, every parameter at
    once (one kernel per step inside a CUDA graph; on the CPU each tensor's own lerp)."""
    targets, sources = list(target.parameters()), list(source.parameters())
    if len(targets) != len(sources):
        raise ValueError(f"{len(targets)} target parameters for {len(sources)} source ones")
    with torch.no_grad():
        torch._foreach_lerp_(targets, sources, tau)


@contextlib.contextmanager
def frozen(*modules: nn.Module) -> Iterator[None]:
    """Build the graph through ``modules`` without asking for their weight gradients (an
    actor's loss through the critics: the gradient reaches the actions only)."""
    params = [p for m in modules for p in m.parameters()]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)
