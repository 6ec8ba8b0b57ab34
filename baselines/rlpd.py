"""RLPD: online RL with offline data (Ball et al. 2023, arXiv:2302.02948), from demonstrations.

SAC with the three changes RLPD makes, the offline data being the demonstration transitions:

1. symmetric sampling: every minibatch is half demonstration transitions, half online
   replay, each half drawn uniformly (the demonstrations never enter the online buffer);
2. LayerNorm in the critics (Dense -> LayerNorm -> ReLU, as RLPD's MLP), which keeps their
   values near the data's and stops the offline half from blowing up the targets;
3. a large ensemble: 10 critics, each regressed on a target whose minimum is over a fresh
   random subset of 2 target critics (REDQ's subset min); the actor ascends the mean of all 10:

    y    = r + gamma * (1 - terminated) * (min_{i in S} Q'_i(s', a') [- alpha log pi(a'|s')]),
           a' ~ pi(.|s'),  S a random 2 of 10, drawn at every critic step
    J_Q  = mean_i E[(Q_i(s, a) - y)^2]
    J_pi = E[alpha log pi(a|s) - mean_i Q_i(s, a)]
    J_a  = alpha * (H[pi] - target_entropy)

The update-to-data ratio ``utd`` (default 1; the paper's 20 is allowed) is the number of
critic steps per env step, each on its own symmetric minibatch; the actor and the
temperature step once per env step, after the last critic step, as RLPD's code does.

Entropy settings are those of the official repository (ikostrikov/rlpd, configs/
rlpd_config.py on sac_config.py, and SACLearner): initial temperature 1, target entropy
-|A|/2, temperature learning rate 3e-4, and the loss J_a above on alpha itself. The entropy
backup term is on by default (``backup_entropy=True``): that is the config's default, used
by its D4RL locomotion command; its sparse-reward commands (AntMaze, Adroit) pass
``backup_entropy=False``, which ``--set backup_entropy=false`` gives here. Learning rates,
batch 256, 2x256 networks, tau and gamma are RLPD's, which are also twin-Q SAC's.

Built on twin-Q SAC (``baselines.sac_twin_q``): its policy, temperature, optimisers, state
and training loop; the critics and the gradient step are RLPD's. Not RLPD's: updates start
after 1000 steps of the initial policy (the harness's, for every SAC), not 5000 random ones;
network initialisation is torch's default, not Xavier.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.context import BatchContext, DemoSet
from baselines.common.networks import TanhGaussianPolicy, frozen, soft_update
from baselines.common.stacked import (
    StackedReplay,
    StackedSymmetricReplay,
    critic_ensembles,
    descend,
    layer_norm_mlp,
)
from baselines.contract import FULL_STEP
from baselines.ibrl import preloaded_buffer
from baselines.offpolicy import action_space, train_members
from baselines.registry import register
from baselines.sac_twin_q import CriticEnsemble, TwinQSACAgent, TwinQSACConfig

CRITIC_STEP = "critic"  # a gradient step of the critics alone


@dataclass
class RLPDConfig(TwinQSACConfig):
    """RLPD's settings (official repository) on twin-Q SAC's; see the module docstring."""

    num_qs: int = 10  # critics in the ensemble
    num_min_qs: int = 2  # target critics the minimum is taken over, drawn at random
    critic_layer_norm: bool = True
    target_entropy_per_action_dim: float = -0.5  # target entropy -|A|/2
    backup_entropy: bool = True  # -alpha log pi(a'|s') in the critic target
    utd: int = 1  # critic steps per env step (the paper's experiments: 20)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.utd < 1 or not 1 <= self.num_min_qs <= self.num_qs:
            raise ValueError("utd must be >= 1 and 1 <= num_min_qs <= num_qs")
        if self.batch_size % 2:
            raise ValueError(
                f"RLPD samples half of each batch from the demonstrations; "
                f"batch_size must be even, got {self.batch_size}"
            )
        # the shared loop takes ``gradient_steps`` minibatches per env step: that is ``utd``
        if self.gradient_steps not in (1, self.utd):
            raise ValueError(
                "RLPD's gradient steps per env step are set by utd; leave gradient_steps alone"
            )
        self.gradient_steps = self.utd


class LayerNormCriticEnsemble(CriticEnsemble):
    """Twin-Q SAC's batched critic ensemble with LayerNorm (own gain and bias per member)
    after every hidden layer, before its ReLU."""

    def __init__(self, obs_dim: int, act_dim: int, hidden_sizes: tuple[int, ...], n: int):
        super().__init__(obs_dim, act_dim, hidden_sizes, n)
        self.norm_gains = torch.nn.ParameterList(
            torch.nn.Parameter(torch.ones(n, 1, width)) for width in hidden_sizes
        )
        self.norm_biases = torch.nn.ParameterList(
            torch.nn.Parameter(torch.zeros(n, 1, width)) for width in hidden_sizes
        )

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        x = torch.cat([obs, act], dim=-1).expand(self.n, -1, -1)
        return layer_norm_mlp(
            x, self.weights, self.biases, self.norm_gains, self.norm_biases
        ).squeeze(-1)


class RLPDAgent(TwinQSACAgent):
    """RLPD for N members: twin-Q SAC's policy and temperature, each member's ensemble of
    LayerNorm critics (its target a minimum over its own random subset of them), minibatches
    half demonstrations, and ``utd`` critic steps per actor step: two kinds of gradient
    step, the full one (critics, actor, temperature) after every ``utd - 1`` critic-only."""

    STEP_KINDS = (FULL_STEP, CRITIC_STEP)

    def __init__(
        self,
        seeds: list[int],
        env_id: str,
        config: RLPDConfig,
        demos: ReplayBuffer,
        device: str = "cpu",
        cuda_graphs: bool = True,
    ):
        self.per_member = config.num_qs
        self.demos = demos  # the demonstration transitions
        self.critic_updates = 0
        super().__init__(seeds, env_id, config, device, cuda_graphs)

    def member_networks(
        self, seed: int, obs_dim: int, act_dim: int, low: np.ndarray, high: np.ndarray
    ) -> tuple[CriticEnsemble, TanhGaussianPolicy]:
        """Twin-Q SAC's policy for this seed; RLPD's ensemble replaces the twin critics,
        drawn next from the same seeded stream."""
        _, policy = super().member_networks(seed, obs_dim, act_dim, low, high)
        ensemble = LayerNormCriticEnsemble if self.config.critic_layer_norm else CriticEnsemble
        return ensemble(obs_dim, act_dim, self.config.hidden_sizes, n=self.config.num_qs), policy

    def make_replay(self, members: int, obs_dim: int, capacity: int) -> StackedReplay:
        return StackedSymmetricReplay(
            self.demos, members, obs_dim, self.act_dim, capacity, self.device
        )

    def extra_state(self) -> dict[str, Any]:
        return {"critic_updates": self.critic_updates}

    def load_extra_state(self, state: dict[str, Any]) -> None:
        self.critic_updates = state["critic_updates"]

    def next_step_kind(self) -> str:
        """Critic-only, but every ``utd``-th step the full one."""
        self.critic_updates += 1
        return FULL_STEP if self.critic_updates % self.config.utd == 0 else CRITIC_STEP

    def cpu_noise(self, kind: str = FULL_STEP) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        # member k draws next_noise, its subset, then (for the actor) new_noise from its stream
        cfg = self.config
        next_noise = torch.zeros((self.members, self.batch_size, self.act_dim))
        new_noise = torch.zeros_like(next_noise)
        subsets = torch.zeros((self.members, cfg.num_min_qs), dtype=torch.long)
        for k, generator in enumerate(self.generators):
            next_noise[k] = torch.randn((self.batch_size, self.act_dim), generator=generator)
            subsets[k] = torch.randperm(cfg.num_qs, generator=generator)[: cfg.num_min_qs]
            if kind == FULL_STEP:
                new_noise[k] = torch.randn((self.batch_size, self.act_dim), generator=generator)
        return next_noise, subsets, new_noise

    def device_noise(
        self, batch: Batch, kind: str = FULL_STEP
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        cfg = self.config
        subsets = torch.rand((self.members, cfg.num_qs), device=self.device).argsort(dim=-1)[
            :, : cfg.num_min_qs
        ]
        return (
            torch.randn(batch.actions.shape, device=self.device),
            subsets,
            torch.randn(batch.actions.shape, device=self.device),
        )

    def gradient_step(
        self,
        batch: Batch,
        noise: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
        kind: str = FULL_STEP,
        **target_inputs: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        cfg = self.config
        next_noise, subsets, new_noise = (t.to(self.device) for t in noise)
        obs, actions, rows = batch.observations, batch.actions, batch.actions.shape[1]
        alpha = self.log_alpha.detach().exp()[:, None]  # (N, 1)

        with torch.no_grad():
            next_actions, next_log_prob = self.policy.sample(
                batch.next_observations, noise=next_noise
            )
            next_q = critic_ensembles(
                self.critics_target, batch.next_observations, next_actions, self.per_member
            )  # (N, Q, B)
            chosen = next_q.gather(1, subsets[:, :, None].expand(-1, -1, rows))
            next_value = chosen.min(dim=1).values
            if cfg.backup_entropy:
                next_value = next_value - alpha * next_log_prob
            y = batch.rewards + cfg.gamma * (1.0 - batch.terminated) * next_value
        q = critic_ensembles(self.critics, obs, actions, self.per_member)
        q_losses = (q - y[:, None]).pow(2).mean(dim=(1, 2))  # per member: mean over Q and B
        descend(self.critic_optimizer, q_losses)
        soft_update(self.critics_target, self.critics, cfg.tau)
        losses = {"q_loss": q_losses.detach()}
        if kind == CRITIC_STEP:
            return losses

        new_actions, log_prob = self.policy.sample(obs, noise=new_noise)
        with frozen(self.critics):
            q_new = critic_ensembles(self.critics, obs, new_actions, self.per_member).mean(dim=1)
        policy_losses = (alpha * log_prob - q_new).mean(-1)
        descend(self.policy_optimizer, policy_losses)

        # RLPD's temperature loss on alpha itself, each member on its own entropy
        entropy = -log_prob.detach().mean(-1)  # (N,)
        alpha_losses = self.log_alpha.exp() * (entropy - self.target_entropy)
        descend(self.alpha_optimizer, alpha_losses)
        return {
            **losses,
            "policy_loss": policy_losses.detach(),
            "alpha": alpha[:, 0],
            "entropy": entropy,
        }


def demo_transitions_or_fail(demos: DemoSet | None) -> DemoSet:
    if demos is None:
        raise ValueError("RLPD needs demonstrations")
    if getattr(demos, "rewards", None) is None:
        raise ValueError(
            "RLPD needs demonstration transitions but the file holds (s, a) pairs "
            "only; regenerate it with `python -m replicate demos`"
        )
    return demos


@register("rlpd", RLPDConfig, needs_demos=True, gpu=True, batchable=True)
def train(bctx: BatchContext, configs: list[RLPDConfig]) -> ReplayBuffer:
    """RLPD (Ball et al. 2023): SAC on half-demonstration batches, 10 LayerNorm critics."""
    demos = demo_transitions_or_fail(bctx.members[0].demos)
    env_id = bctx.shared("env_id")
    obs_dim, act_dim, _, _ = action_space(env_id)
    demo_buffer = preloaded_buffer(demos, obs_dim, act_dim, online_capacity=0)
    return train_members(
        bctx, RLPDAgent(bctx.seeds, env_id, configs[0], demo_buffer, bctx.device, bctx.cuda_graphs)
    )
