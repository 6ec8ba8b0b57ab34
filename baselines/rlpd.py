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

import copy
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.context import DemoSet, TrainContext
from baselines.common.device import GraphedStep, make_adam
from baselines.common.networks import soft_update
from baselines.common.stacked import layer_norm_mlp
from baselines.ibrl import preloaded_buffer
from baselines.registry import register
from baselines.sac import PolicyExplorer, frozen, run_off_policy
from baselines.sac_twin_q import CriticEnsemble, TwinQSACAgent, TwinQSACConfig
from envs import make_env


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


class SymmetricReplay(ReplayBuffer):
    """The online replay buffer, whose every sample is half demonstration transitions."""

    def __init__(self, demos: DemoSet, obs_dim: int, act_dim: int, capacity: int):
        super().__init__(obs_dim, act_dim, capacity)
        self.demos = preloaded_buffer(demos, obs_dim, act_dim, online_capacity=0)

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """``batch_size // 2`` demonstration rows first, then the online rows."""
        offline = self.demos.sample(batch_size // 2, rng)
        online = super().sample(batch_size - batch_size // 2, rng)
        return Batch(
            *(
                torch.cat([getattr(offline, name), getattr(online, name)])
                for name in (
                    "observations",
                    "actions",
                    "rewards",
                    "next_observations",
                    "terminated",
                )
            )
        )


class RLPDAgent(TwinQSACAgent):
    """Twin-Q SAC's policy and temperature with RLPD's critics and gradient steps."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        config: RLPDConfig,
        seed: int,
        device: str = "cpu",
        cuda_graphs: bool = True,
    ):
        # the policy, temperature and noise stream twin-Q SAC has for this seed
        super().__init__(
            obs_dim, act_dim, action_low, action_high, config, seed, device, cuda_graphs
        )
        # RLPD's ensemble replaces the twin critics, drawn next from the same seeded stream
        ensemble = LayerNormCriticEnsemble if config.critic_layer_norm else CriticEnsemble
        self.critics = ensemble(obs_dim, act_dim, config.hidden_sizes, n=config.num_qs).to(
            self.device
        )
        self.critics_target = copy.deepcopy(self.critics)
        self.critic_optimizer = make_adam(
            self.critics.parameters(), config.learning_rate, self.device, True
        )
        self.critic_step = GraphedStep(self._critic_step, self.device, cuda_graphs)
        self.actor_step = GraphedStep(self._actor_step, self.device, cuda_graphs)
        self.critic_updates = 0

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "critic_updates": self.critic_updates}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        state = dict(state)
        self.critic_updates = state.pop("critic_updates")
        super().load_state_dict(state)

    def update(self, batch: Batch) -> dict[str, torch.Tensor]:
        """One critic step on ``batch``; after every ``utd``-th, one actor and temperature step."""
        cfg = self.config
        rows, act_dim = batch.actions.shape
        next_noise = torch.randn((rows, act_dim), generator=self.noise, device=self.device)
        subset = torch.randperm(cfg.num_qs, generator=self.noise, device=self.device)[
            : cfg.num_min_qs
        ]
        losses = dict(
            self.critic_step(
                obs=batch.observations,
                actions=batch.actions,
                rewards=batch.rewards,
                next_obs=batch.next_observations,
                terminated=batch.terminated,
                next_noise=next_noise,
                subset=subset,
            )
        )
        self.critic_updates += 1
        if self.critic_updates % cfg.utd == 0:
            new_noise = torch.randn((rows, act_dim), generator=self.noise, device=self.device)
            losses.update(self.actor_step(obs=batch.observations, new_noise=new_noise))
        return losses

    def next_state_value(
        self,
        next_obs: torch.Tensor,
        next_noise: torch.Tensor,
        alpha: torch.Tensor,
        subset: torch.Tensor,
    ) -> torch.Tensor:
        """min over the target critics in ``subset`` at a' ~ pi(.|s'), less alpha log pi(a'|s')
        where the entropy is backed up."""
        next_actions, next_log_prob = self.policy.sample(next_obs, noise=next_noise)
        next_value = self.critics_target(next_obs, next_actions)[subset].min(dim=0).values
        if self.config.backup_entropy:
            next_value = next_value - alpha * next_log_prob
        return next_value

    def _critic_step(
        self,
        obs: torch.Tensor,
        actions: torch.Tensor,
        rewards: torch.Tensor,
        next_obs: torch.Tensor,
        terminated: torch.Tensor,
        next_noise: torch.Tensor,
        subset: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        cfg = self.config
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            next_value = self.next_state_value(next_obs, next_noise, alpha, subset)
            y = rewards + cfg.gamma * (1.0 - terminated) * next_value
        q_loss = (self.critics(obs, actions) - y).pow(2).mean()
        self.critic_optimizer.zero_grad()
        q_loss.backward()
        self.critic_optimizer.step()
        soft_update(self.critics_target, self.critics, cfg.tau)
        return {"q_loss": q_loss.detach()}

    def _actor_step(self, obs: torch.Tensor, new_noise: torch.Tensor) -> dict[str, torch.Tensor]:
        alpha = self.log_alpha.detach().exp()
        new_actions, log_prob = self.policy.sample(obs, noise=new_noise)
        with frozen(self.critics):
            q_new = self.critics(obs, new_actions).mean(dim=0)
        policy_loss = (alpha * log_prob - q_new).mean()
        self.policy_optimizer.zero_grad()
        policy_loss.backward()
        self.policy_optimizer.step()

        # RLPD's temperature loss: alpha falls while the entropy is above its target
        entropy = -log_prob.detach().mean()
        alpha_loss = self.log_alpha.exp() * (entropy - self.target_entropy)
        self.alpha_optimizer.zero_grad()
        alpha_loss.sum().backward()
        self.alpha_optimizer.step()
        return {"policy_loss": policy_loss.detach(), "alpha": alpha, "entropy": entropy}


def demo_transitions_or_fail(demos: DemoSet | None) -> DemoSet:
    if demos is None:
        raise ValueError("RLPD needs demonstrations")
    if getattr(demos, "rewards", None) is None:
        raise ValueError(
            "RLPD needs demonstration transitions but the file holds (s, a) pairs "
            "only; regenerate it with `python -m replicate demos`"
        )
    return demos


@register("rlpd", RLPDConfig, needs_demos=True, gpu=True)
def train(ctx: TrainContext, config: RLPDConfig) -> SymmetricReplay:
    """RLPD (Ball et al. 2023): SAC on half-demonstration batches, 10 LayerNorm critics."""
    demos = demo_transitions_or_fail(ctx.demos)
    probe = make_env(ctx.env_id)
    obs_dim, space = probe.observation_space.shape[0], probe.action_space
    probe.close()
    agent = RLPDAgent(
        obs_dim,
        space.shape[0],
        space.low,
        space.high,
        config,
        ctx.seed,
        device=ctx.device,
        cuda_graphs=ctx.cuda_graphs,
    )
    buffer = SymmetricReplay(
        demos, obs_dim, space.shape[0], min(config.buffer_size, ctx.total_steps)
    )
    return run_off_policy(ctx, agent, PolicyExplorer(agent), buffer)
