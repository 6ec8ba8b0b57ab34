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
training loop is SAC's (``baselines.sac.run_off_policy``).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.context import TrainContext
from baselines.common.device import GraphedStep, make_adam
from baselines.common.networks import TanhGaussianPolicy, soft_update
from baselines.registry import register
from baselines.sac import PolicyActor, PolicyExplorer, frozen, run_off_policy
from envs import make_env


@dataclass
class TwinQSACConfig:
    """Stable-Baselines3's SAC defaults, except updates start after 1000 steps as in ``sac``."""

    learning_rate: float = 3e-4
    batch_size: int = 256
    hidden_sizes: tuple[int, ...] = (256, 256)
    buffer_size: int = 1_000_000
    gamma: float = 0.99
    tau: float = 0.005
    initial_alpha: float = 1.0
    target_entropy_per_action_dim: float = -1.0  # target entropy = this * |A|
    learning_starts: int = 1000
    # uniform-random actions before the policy acts (the SAC authors' code: 1,000 or
    # 10,000); 0, the default, is kept out of a run's address (replicate/runner.py)
    random_start_steps: int = 0
    gradient_steps: int = 1
    torch_threads: int = 1

    def __post_init__(self) -> None:
        self.hidden_sizes = tuple(int(w) for w in self.hidden_sizes)
        if self.batch_size <= 0 or self.buffer_size <= 0 or self.gradient_steps < 1:
            raise ValueError("batch_size, buffer_size and gradient_steps must be positive")
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


class TwinQSACAgent(PolicyActor):
    """Policy, twin critics with their targets, the temperature, and one gradient step."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        config: TwinQSACConfig,
        seed: int,
        device: str = "cpu",
        cuda_graphs: bool = True,
    ):
        self.config = config
        self.device = torch.device(device)
        torch.manual_seed(seed)
        hidden = config.hidden_sizes
        self.critics = CriticEnsemble(obs_dim, act_dim, hidden).to(self.device)
        self.critics_target = copy.deepcopy(self.critics)
        self.policy = TanhGaussianPolicy(obs_dim, act_dim, action_low, action_high, hidden).to(
            self.device
        )
        self.log_alpha = torch.tensor(
            [math.log(config.initial_alpha)], device=self.device, requires_grad=True
        )
        self.target_entropy = config.target_entropy_per_action_dim * act_dim
        lr = config.learning_rate
        # fused Adam: one kernel per optimiser step instead of a loop over parameters
        self.critic_optimizer = make_adam(self.critics.parameters(), lr, self.device, True)
        self.policy_optimizer = make_adam(self.policy.parameters(), lr, self.device, True)
        self.alpha_optimizer = make_adam([self.log_alpha], lr, self.device, True)
        self.noise = torch.Generator(device=self.device).manual_seed(seed + 1)
        self.gradient_step = GraphedStep(self._gradient_step, self.device, cuda_graphs)

    def state_dict(self) -> dict[str, Any]:
        modules = (
            "critics",
            "critics_target",
            "policy",
            "critic_optimizer",
            "policy_optimizer",
            "alpha_optimizer",
        )
        state = {name: getattr(self, name).state_dict() for name in modules}
        state["log_alpha"] = self.log_alpha.detach().clone()
        state["noise"] = self.noise.get_state()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name, value in state.items():
            if name == "noise":
                self.noise.set_state(value)
            elif name == "log_alpha":
                with torch.no_grad():
                    self.log_alpha.copy_(value)
            else:
                getattr(self, name).load_state_dict(value)

    def update(self, batch: Batch) -> dict[str, torch.Tensor]:
        """One gradient step on ``batch``. The losses come back as 0-d tensors: reading one
        waits for the GPU, so the training loop reads them seldom."""
        rows, act_dim = batch.actions.shape
        # both draws precede the step, in the order the step uses them
        next_noise = torch.randn((rows, act_dim), generator=self.noise, device=self.device)
        new_noise = torch.randn((rows, act_dim), generator=self.noise, device=self.device)
        return self.gradient_step(
            obs=batch.observations,
            actions=batch.actions,
            rewards=batch.rewards,
            next_obs=batch.next_observations,
            terminated=batch.terminated,
            next_noise=next_noise,
            new_noise=new_noise,
            **self.target_inputs(batch),
        )

    def target_inputs(self, batch: Batch) -> dict[str, torch.Tensor]:
        """Further tensors that ``next_state_value`` takes (IBRL: the imitation action at s')."""
        return {}

    def next_state_value(
        self, next_obs: torch.Tensor, next_noise: torch.Tensor, alpha: torch.Tensor
    ) -> torch.Tensor:
        """Soft value of s' under the target critics: min_i Q'_i(s', a') - alpha log pi(a'|s')."""
        next_actions, next_log_prob = self.policy.sample(next_obs, noise=next_noise)
        next_q = self.critics_target(next_obs, next_actions).min(dim=0).values
        return next_q - alpha * next_log_prob

    def _gradient_step(
        self,
        obs: torch.Tensor,
        actions: torch.Tensor,
        rewards: torch.Tensor,
        next_obs: torch.Tensor,
        terminated: torch.Tensor,
        next_noise: torch.Tensor,
        new_noise: torch.Tensor,
        **target_inputs: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        cfg = self.config
        alpha = self.log_alpha.detach().exp()

        # Critics regress on the soft value of the next state under the target critics.
        with torch.no_grad():
            next_value = self.next_state_value(next_obs, next_noise, alpha, **target_inputs)
            y = rewards + cfg.gamma * (1.0 - terminated) * next_value
        q_loss = 0.5 * (self.critics(obs, actions) - y).pow(2).mean(dim=1).sum()
        self.critic_optimizer.zero_grad()
        q_loss.backward()
        self.critic_optimizer.step()

        # The policy follows the smaller critic through the reparameterised action.
        new_actions, log_prob = self.policy.sample(obs, noise=new_noise)
        with frozen(self.critics):
            q_new = self.critics(obs, new_actions).min(dim=0).values
        policy_loss = (alpha * log_prob - q_new).mean()
        self.policy_optimizer.zero_grad()
        policy_loss.backward()
        self.policy_optimizer.step()

        # The temperature rises when the entropy falls below its target, and falls otherwise.
        alpha_loss = -(self.log_alpha * (log_prob.detach() + self.target_entropy)).mean()
        self.alpha_optimizer.zero_grad()
        alpha_loss.backward()
        self.alpha_optimizer.step()

        soft_update(self.critics_target, self.critics, cfg.tau)
        return {
            "q_loss": q_loss.detach(),
            "policy_loss": policy_loss.detach(),
            "alpha": alpha,
            "entropy": -log_prob.detach().mean(),
        }


def build_agent(ctx: TrainContext, config: TwinQSACConfig) -> TwinQSACAgent:
    probe = make_env(ctx.env_id)
    space = probe.action_space
    agent = TwinQSACAgent(
        probe.observation_space.shape[0],
        space.shape[0],
        space.low,
        space.high,
        config,
        seed=ctx.seed,
        device=ctx.device,
        cuda_graphs=ctx.cuda_graphs,
    )
    probe.close()
    return agent


@register("sac-twin-q", TwinQSACConfig, gpu=True)
def train(ctx: TrainContext, config: TwinQSACConfig) -> ReplayBuffer:
    """SAC with twin target critics and learned temperature (SB3's SAC), for benches and experts."""
    agent = build_agent(ctx, config)
    return run_off_policy(ctx, agent, PolicyExplorer(agent))
