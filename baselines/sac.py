"""Soft Actor-Critic as the DRL-EG paper uses it (Haarnoja et al. 2018, arXiv:1801.01290).

Five networks: two soft Q-functions Q1, Q2, a state-value V, its Polyak-averaged copy V',
and a tanh-squashed Gaussian policy pi. Per gradient step (paper eqs. 13-17):

    y_q = reward_scale * r + gamma * (1 - terminated) * V'(s')
    y_v = min(Q1, Q2)(s, a~pi) - log pi(a|s)
    J_pi = E[log pi(a|s) - min(Q1, Q2)(s, a~pi)]

The entropy temperature is 1 with rewards multiplied by ``reward_scale``, as in the SAC
paper. Only termination stops bootstrapping; a time-limit truncation keeps V'(s').
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.context import BatchContext
from baselines.common.networks import QNetwork, TanhGaussianPolicy, VNetwork, frozen, soft_update
from baselines.common.stacked import StackedMLP, critic_pairs, descend, member_adam, pair_critics
from baselines.contract import FULL_STEP
from baselines.offpolicy import OffPolicyAgent, OffPolicyConfig, stack_policies, train_members
from baselines.registry import register


@dataclass
class SACConfig(OffPolicyConfig):
    """Hyperparameters; defaults are Table 1 of Haarnoja et al. 2018 (arXiv:1801.01290, App. D)."""

    reward_scale: float = 5.0  # Hopper, Walker2d, HalfCheetah and Ant all use 5 in the SAC paper


def q_target(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    next_values: torch.Tensor,
    gamma: float,
    reward_scale: float,
) -> torch.Tensor:
    """y_q = scale * r + gamma * (1 - terminated) * V'(s')."""
    return reward_scale * rewards + gamma * (1.0 - terminated) * next_values


def v_target(q_min: torch.Tensor, log_prob: torch.Tensor) -> torch.Tensor:
    """y_v = min_i Q_i(s, a) - log pi(a|s), with a ~ pi(.|s)."""
    return q_min - log_prob


@dataclass
class SACNetworks:
    """One member's initial networks, drawn from its seed alone, so SAC and DRL-EG with one
    seed start identical and a member's weights do not depend on its batch."""

    q1: QNetwork
    q2: QNetwork
    v: VNetwork
    policy: TanhGaussianPolicy

    @classmethod
    def initial(
        cls,
        seed: int,
        obs_dim: int,
        act_dim: int,
        low: np.ndarray,
        high: np.ndarray,
        config: SACConfig,
    ) -> SACNetworks:
        torch.manual_seed(seed)
        hidden = config.hidden_sizes
        q1, q2 = QNetwork(obs_dim, act_dim, hidden), QNetwork(obs_dim, act_dim, hidden)
        v = VNetwork(obs_dim, hidden)
        return cls(q1, q2, v, TanhGaussianPolicy(obs_dim, act_dim, low, high, hidden))


class SACAgent(OffPolicyAgent):
    """The paper's V-network SAC for N members: five networks each, and the gradient step."""

    MODULES = (
        "critics",
        "v",
        "v_target",
        "policy",
        "q_optimizer",
        "v_optimizer",
        "policy_optimizer",
    )

    def build(self, obs_dim: int, low: np.ndarray, high: np.ndarray) -> None:
        config = self.config
        nets = [
            SACNetworks.initial(s, obs_dim, self.act_dim, low, high, config) for s in self.seeds
        ]
        self.critics = pair_critics([n.q1.net for n in nets], [n.q2.net for n in nets]).to(
            self.device
        )
        self.v = StackedMLP.stack([n.v.net for n in nets]).to(self.device)
        self.v_target = copy.deepcopy(self.v)
        self.policy = stack_policies([n.policy for n in nets], self.device)
        lr = config.learning_rate
        self.q_optimizer = member_adam(self.critics.parameters(), lr, self.device)
        self.v_optimizer = member_adam(self.v.parameters(), lr, self.device)
        self.policy_optimizer = member_adam(self.policy.parameters(), lr, self.device)

    def cpu_noise(self, kind: str = FULL_STEP) -> torch.Tensor:
        return self.member_noise(self.batch_size).to(self.device)

    def device_noise(self, batch: Batch, kind: str = FULL_STEP) -> torch.Tensor:
        return torch.randn(batch.actions.shape, device=self.device)

    def gradient_step(
        self, batch: Batch, noise: torch.Tensor, kind: str = FULL_STEP
    ) -> dict[str, torch.Tensor]:
        cfg = self.config
        obs, actions = batch.observations, batch.actions
        with torch.no_grad():
            y_q = q_target(
                batch.rewards,
                batch.terminated,
                self.v_target(batch.next_observations).squeeze(-1),
                cfg.gamma,
                cfg.reward_scale,
            )
        q = critic_pairs(self.critics, obs, actions)  # (N, 2, B)
        q_losses = 0.5 * (q - y_q[:, None]).pow(2).mean(-1).sum(-1)  # per member
        descend(self.q_optimizer, q_losses)

        new_actions, log_prob = self.policy.sample(obs, noise=noise)
        with frozen(self.critics):
            q_new = critic_pairs(self.critics, obs, new_actions).min(dim=1).values
        v_losses = 0.5 * (self.v(obs).squeeze(-1) - v_target(q_new, log_prob).detach()).pow(2).mean(
            -1
        )
        policy_losses = (log_prob - q_new).mean(-1)
        descend(self.v_optimizer, v_losses)
        descend(self.policy_optimizer, policy_losses)

        soft_update(self.v_target, self.v, cfg.tau)
        return {
            "q_loss": q_losses.detach(),
            "v_loss": v_losses.detach(),
            "policy_loss": policy_losses.detach(),
            "entropy": -log_prob.detach().mean(-1),
        }


@register("sac", SACConfig, gpu=True, batchable=True)
def train(bctx: BatchContext, configs: list[SACConfig]) -> ReplayBuffer:
    """SAC with a V network (Haarnoja et al. 2018), the paper's baseline and DRL-EG's base."""
    return train_members(
        bctx, SACAgent(bctx.seeds, bctx.shared("env_id"), configs[0], bctx.device, bctx.cuda_graphs)
    )
