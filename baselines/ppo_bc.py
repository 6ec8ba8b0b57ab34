"""PPO with behaviour-cloning pre-training: the paper's "PPO with pre-train" baseline.

The policy mean is first regressed on the demonstration pairs (mean squared error, the
observation normaliser seeded with the demonstration states), then trained by PPO exactly
as ``baselines.ppo``. The paper gives no details of its pre-training; the values below are
the harness's choice, recorded in every run's spec.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from baselines.common.context import DemoSet, TrainContext
from baselines.ppo import PPOAgent, PPOConfig, build_agent, run_ppo
from baselines.registry import register


@dataclass
class PPOBCConfig(PPOConfig):
    bc_steps: int = 2000  # gradient steps of behaviour cloning before PPO starts
    bc_batch_size: int = 64
    bc_learning_rate: float = 1e-3

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.bc_steps < 0 or self.bc_batch_size <= 0:
            raise ValueError("bc_steps must be >= 0 and bc_batch_size > 0")


def bc_loss(predicted_actions: torch.Tensor, demo_actions: torch.Tensor) -> torch.Tensor:
    """Mean over pairs of the squared error summed over action dimensions."""
    return (predicted_actions - demo_actions).pow(2).sum(-1).mean()


def behaviour_clone(agent: PPOAgent, demos: DemoSet, config: PPOBCConfig, seed: int) -> list[float]:
    """Fit the policy mean to the demonstrations; return the loss of every step."""
    if config.normalize_observations:
        agent.obs_stats.update(demos.observations)
    obs = torch.as_tensor(agent.normalize(demos.observations))
    actions = torch.as_tensor(np.asarray(demos.actions, dtype=np.float32))
    optimizer = torch.optim.Adam(agent.actor_mean.parameters(), lr=config.bc_learning_rate)
    rng = np.random.default_rng([seed, 3])
    losses = []
    for _ in range(config.bc_steps):
        idx = torch.as_tensor(rng.integers(0, len(obs), size=config.bc_batch_size))
        loss = bc_loss(agent.actor_mean(obs[idx]), actions[idx])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    return losses


@register("ppo-bc", PPOBCConfig, needs_demos=True)
def train(ctx: TrainContext, config: PPOBCConfig) -> None:
    """PPO whose policy is pre-trained by behaviour cloning on the demonstrations."""
    if ctx.demos is None:
        raise ValueError("PPO+BC needs demonstrations")
    agent = build_agent(ctx, config)
    torch.set_num_threads(config.torch_threads)
    behaviour_clone(agent, ctx.demos, config, ctx.seed)
    run_ppo(ctx, agent)
