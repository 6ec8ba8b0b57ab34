"""SAC with twin target critics and a learned temperature (Haarnoja et al. 2018, arXiv:1812.05905).

The SAC most libraries ship (Stable-Baselines3, CleanRL): no V network; two soft Q-functions
with Polyak-averaged copies, and an entropy temperature alpha tuned towards a target
entropy of -|A|. Per gradient step:

    y = r + gamma * (1 - terminated) * (min_i Q'_i(s', a') - alpha * log pi(a'|s')),  a' ~ pi(.|s')
    J_Q   = 1/2 sum_i E[(Q_i(s, a) - y)^2]
    J_pi  = E[alpha * log pi(a|s) - min_i Q_i(s, a)],  a ~ pi(.|s) reparameterised
    J_a   = E[-log alpha * (log pi(a|s) + target_entropy)]

It is the harness's like-for-like counterpart of SB3's SAC in the throughput bench, and the
expert trainer for envs where the paper's V-network SAC stalls (Ant). Both critics live in
one module whose layers are batched matrix products, so one call evaluates the pair. The
training loop is the SAC family's (``baselines.offpolicy.run_off_policy``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.context import BatchContext
from baselines.common.networks import TanhGaussianPolicy, frozen, soft_update
from baselines.common.stacked import StackedMLP, StackedNormMLP, critic_pairs, descend, member_adam
from baselines.contract import FULL_STEP
from baselines.offpolicy import OffPolicyAgent, OffPolicyConfig, stack_policies, train_members
from baselines.registry import register


@dataclass
class TwinQSACConfig(OffPolicyConfig):
    """Stable-Baselines3's SAC defaults, except updates start after 1000 steps as in ``sac``."""

    initial_alpha: float = 1.0
    target_entropy_per_action_dim: float = -1.0  # target entropy = this * |A|

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.initial_alpha <= 0:
            raise ValueError("initial_alpha must be positive")


class CriticEnsemble(nn.Module):
    """``n`` Q-networks evaluated together: each layer is one batched matrix product.

    Layer k holds weights of shape (n, in, out), initialised per member as ``nn.Linear``
    would (uniform in +-1/sqrt(in)). ``forward`` returns Q of shape (n, batch).
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden_sizes: tuple[int, ...], n: int = 2):
        super().__init__()
        sizes = [obs_dim + act_dim, *hidden_sizes, 1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
            bound = 1.0 / math.sqrt(fan_in)
            self.weights.append(
                nn.Parameter(torch.empty(n, fan_in, fan_out).uniform_(-bound, bound))
            )
            self.biases.append(nn.Parameter(torch.empty(n, 1, fan_out).uniform_(-bound, bound)))
        self.n = n

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        x = torch.cat([obs, act], dim=-1).expand(self.n, -1, -1)
        last = len(self.weights) - 1
        for k, (weight, bias) in enumerate(zip(self.weights, self.biases)):
            x = torch.baddbmm(bias, x, weight)
            if k < last:
                x = torch.relu(x)
        return x.squeeze(-1)


class TwinQSACAgent(OffPolicyAgent):
    """Twin-Q, learned-temperature SAC for N members: the networks and the gradient step."""

    MODULES = (
        "critics",
        "critics_target",
        "policy",
        "critic_optimizer",
        "policy_optimizer",
        "alpha_optimizer",
    )
    TENSORS = ("log_alpha",)

    def build(self, obs_dim: int, low: np.ndarray, high: np.ndarray) -> None:
        config = self.config
        nets = [self.member_networks(s, obs_dim, self.act_dim, low, high) for s in self.seeds]
        self.critics = self._stack_ensembles([critics for critics, _ in nets]).to(self.device)
        self.critics_target = copy.deepcopy(self.critics)
        self.policy = stack_policies([policy for _, policy in nets], self.device)
        self.log_alpha = torch.full(
            (self.members,), math.log(config.initial_alpha), device=self.device
        ).requires_grad_(True)
        self.target_entropy = config.target_entropy_per_action_dim * self.act_dim
        lr = config.learning_rate
        self.critic_optimizer = member_adam(self.critics.parameters(), lr, self.device)
        self.policy_optimizer = member_adam(self.policy.parameters(), lr, self.device)
        self.alpha_optimizer = member_adam([self.log_alpha], lr, self.device)

    def member_networks(
        self, seed: int, obs_dim: int, act_dim: int, low: np.ndarray, high: np.ndarray
    ) -> tuple[CriticEnsemble, TanhGaussianPolicy]:
        """Member ``seed``'s initial critics and policy, drawn from its seed alone."""
        torch.manual_seed(seed)
        hidden = self.config.hidden_sizes
        critics = CriticEnsemble(obs_dim, act_dim, hidden)
        return critics, TanhGaussianPolicy(obs_dim, act_dim, low, high, hidden)

    @staticmethod
    def _stack_ensembles(ensembles: list) -> StackedMLP:
        """Each member's (Q, in, out) critic ensemble, member-major, as one stack of N * Q
        (with each critic's LayerNorm gains and biases where the ensembles have them)."""

        def joined(name: str) -> list[torch.Tensor]:
            layers = getattr(ensembles[0], name)
            return [
                torch.cat([getattr(e, name)[i].detach() for e in ensembles])
                for i in range(len(layers))
            ]

        if hasattr(ensembles[0], "norm_gains"):
            return StackedNormMLP(
                joined("weights"), joined("biases"), joined("norm_gains"), joined("norm_biases")
            )
        return StackedMLP(joined("weights"), joined("biases"))

    def cpu_noise(self, kind: str = FULL_STEP) -> tuple[torch.Tensor, torch.Tensor]:
        # member k draws next_noise, then new_noise, from its own stream
        next_noise = torch.zeros((self.members, self.batch_size, self.act_dim))
        new_noise = torch.zeros_like(next_noise)
        for k, generator in enumerate(self.generators):
            next_noise[k] = torch.randn((self.batch_size, self.act_dim), generator=generator)
            new_noise[k] = torch.randn((self.batch_size, self.act_dim), generator=generator)
        return next_noise.to(self.device), new_noise.to(self.device)

    def device_noise(
        self, batch: Batch, kind: str = FULL_STEP
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return (
            torch.randn(batch.actions.shape, device=self.device),
            torch.randn(batch.actions.shape, device=self.device),
        )

    def next_state_value(
        self,
        next_obs: torch.Tensor,
        next_noise: torch.Tensor,
        alpha: torch.Tensor,
        **target_inputs: torch.Tensor,
    ) -> torch.Tensor:
        """Each member's soft value of s' (N, B) under its target critics."""
        next_actions, next_log_prob = self.policy.sample(next_obs, noise=next_noise)
        return self.bootstrap_q(next_obs, next_actions, **target_inputs) - alpha * next_log_prob

    def bootstrap_q(
        self, next_obs: torch.Tensor, next_actions: torch.Tensor, **target_inputs: torch.Tensor
    ) -> torch.Tensor:
        """The target Q of s' the value bootstraps from (IBRL's: the better of two actions)."""
        return self.target_q(next_obs, next_actions)

    def target_q(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """The minimum of each member's two target critics, (N, B)."""
        return critic_pairs(self.critics_target, obs, actions).min(dim=1).values

    def gradient_step(
        self,
        batch: Batch,
        noise: tuple[torch.Tensor, torch.Tensor],
        kind: str = FULL_STEP,
        **target_inputs: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        cfg = self.config
        next_noise, new_noise = noise
        obs, actions = batch.observations, batch.actions
        alpha = self.log_alpha.detach().exp()[:, None]  # (N, 1)

        with torch.no_grad():
            next_value = self.next_state_value(
                batch.next_observations, next_noise, alpha, **target_inputs
            )
            y = batch.rewards + cfg.gamma * (1.0 - batch.terminated) * next_value
        q_losses = 0.5 * (critic_pairs(self.critics, obs, actions) - y[:, None]).pow(2).mean(
            -1
        ).sum(-1)
        descend(self.critic_optimizer, q_losses)

        new_actions, log_prob = self.policy.sample(obs, noise=new_noise)
        with frozen(self.critics):
            q_new = critic_pairs(self.critics, obs, new_actions).min(dim=1).values
        policy_losses = (alpha * log_prob - q_new).mean(-1)
        descend(self.policy_optimizer, policy_losses)

        alpha_losses = -(self.log_alpha[:, None] * (log_prob.detach() + self.target_entropy)).mean(
            -1
        )
        descend(self.alpha_optimizer, alpha_losses)

        soft_update(self.critics_target, self.critics, cfg.tau)
        return {
            "q_loss": q_losses.detach(),
            "policy_loss": policy_losses.detach(),
            "alpha": alpha[:, 0],
            "entropy": -log_prob.detach().mean(-1),
        }


@register("sac-twin-q", TwinQSACConfig, gpu=True, batchable=True)
def train(bctx: BatchContext, configs: list[TwinQSACConfig]) -> ReplayBuffer:
    """SAC with twin target critics and learned temperature (SB3's SAC), for benches and experts."""
    env_id = bctx.shared("env_id")
    return train_members(
        bctx, TwinQSACAgent(bctx.seeds, env_id, configs[0], bctx.device, bctx.cuda_graphs)
    )
