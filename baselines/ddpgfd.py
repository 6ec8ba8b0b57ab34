"""DDPG from Demonstrations (Vecerik et al. 2017, arXiv:1707.08817), the paper's DDPGfD baseline.

DDPG (Lillicrap et al. 2016, arXiv:1509.02971) with four changes from Vecerik et al.:

1. the demonstration transitions sit permanently in a prioritized replay buffer;
2. priorities p_i = delta_i^2 + lambda3 |grad_a Q(s_i, a_i)|^2 + eps + eps_D (demos only),
   sampled with probability p_i^alpha / sum_k p_k^alpha and corrected by importance
   weights (N P(i))^-beta, beta annealed to 1;
3. the critic loss mixes 1-step and n-step returns: L_1 + lambda1 L_n;
4. L2 regularisation lambda2 ||theta||^2 on actor and critic.

Vecerik et al. give no numbers for alpha, beta, the epsilons, lambda1, lambda2 or n; the
defaults below take them from DQfD (Hester et al. 2018, arXiv:1704.03732, Sec. 4), the
same authors' discrete-action version; lambda3 = 1 is the harness's choice. Learning
rates, tau and the network sizes are Lillicrap et al.'s; exploration is Gaussian noise.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from baselines.common.checkpoint import OneRunCheckpoints
from baselines.common.context import DemoSet, TrainContext
from baselines.common.device import flush_denormals
from baselines.common.evaluation import EVAL_SEED_OFFSET
from baselines.common.networks import QNetwork, frozen, mlp, soft_update
from baselines.common.prioritized import PrioritizedBatch, PrioritizedReplayBuffer
from baselines.registry import register
from envs import make_env


@dataclass
class DDPGfDConfig:
    """Hyperparameters with their sources (see the module docstring)."""

    actor_learning_rate: float = 1e-4  # Lillicrap et al. 2016, Sec. 7
    critic_learning_rate: float = 1e-3  # Lillicrap et al. 2016, Sec. 7
    hidden_sizes: tuple[int, ...] = (400, 300)  # Lillicrap et al. 2016, Sec. 7
    batch_size: int = 64  # Lillicrap et al. 2016, Sec. 7
    buffer_size: int = 1_000_000  # Lillicrap et al. 2016, Sec. 7
    gamma: float = 0.99  # Lillicrap et al. 2016
    tau: float = 0.001  # Lillicrap et al. 2016
    n_step: int = 10  # DQfD
    lambda_n_step: float = 1.0  # lambda1, DQfD
    l2_coef: float = 1e-5  # lambda2, DQfD
    lambda_actor_priority: float = 1.0  # lambda3, harness choice (not given)
    priority_alpha: float = 0.4  # DQfD
    priority_beta0: float = 0.6  # DQfD; annealed linearly to 1 over the run
    priority_eps: float = 1e-3  # eps_a, DQfD
    priority_eps_demo: float = 1.0  # eps_d, DQfD
    exploration_noise: float = 0.1  # Gaussian std as a fraction of the action half-range
    learning_starts: int = 1  # demonstrations fill the buffer, so learning starts at once
    gradient_steps: int = 1  # per env step, as for SAC in the harness
    torch_threads: int = 1
    # Denormals treated as zero (TensorFlow's default on x86 CPUs; every trainer of the
    # harness does): the saturated tanh of the actor makes its gradients denormal, which
    # slowed CPU training tenfold. False computes with them, for comparison.
    flush_denormals: bool = True

    def __post_init__(self) -> None:
        self.hidden_sizes = tuple(int(w) for w in self.hidden_sizes)
        if (
            self.n_step < 1
            or self.batch_size <= 0
            or self.buffer_size <= 0
            or self.gradient_steps < 1
        ):
            raise ValueError("n_step, batch_size, buffer_size and gradient_steps must be positive")
        if not 0.0 <= self.priority_alpha <= 1.0 or not 0.0 <= self.priority_beta0 <= 1.0:
            raise ValueError("priority_alpha and priority_beta0 must be in [0, 1]")


def n_step_target(
    n_step_returns: torch.Tensor, n_step_discounts: torch.Tensor, bootstrap_values: torch.Tensor
) -> torch.Tensor:
    """y_n = sum_{k<m} gamma^k r_{t+k} + gamma^m Q'(s_{t+m}, mu'(s_{t+m})); the discount is 0
    where the episode terminated inside the m steps."""
    return n_step_returns + n_step_discounts * bootstrap_values


def transition_priorities(
    td_errors: np.ndarray, action_gradients: np.ndarray, is_demo: np.ndarray, config: DDPGfDConfig
) -> np.ndarray:
    """p_i = delta_i^2 + lambda3 |grad_a Q|^2 + eps + eps_D [i is a demonstration]."""
    return (
        td_errors**2
        + config.lambda_actor_priority * (action_gradients**2).sum(-1)
        + config.priority_eps
        + config.priority_eps_demo * is_demo
    )


def l2_penalty(module: nn.Module) -> torch.Tensor:
    return sum(p.pow(2).sum() for name, p in module.named_parameters() if "weight" in name)


class DeterministicActor(nn.Module):
    """mu(s) = bias + scale * tanh(f(s)): a deterministic policy inside the action box."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        low: np.ndarray,
        high: np.ndarray,
        hidden_sizes: tuple[int, ...],
    ):
        super().__init__()
        self.net = mlp(obs_dim, act_dim, hidden_sizes)
        low_t, high_t = (torch.as_tensor(x, dtype=torch.float32) for x in (low, high))
        self.register_buffer("action_scale", (high_t - low_t) / 2.0)
        self.register_buffer("action_bias", (high_t + low_t) / 2.0)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.action_bias + self.action_scale * torch.tanh(self.net(obs))


class DDPGfDAgent:
    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        low: np.ndarray,
        high: np.ndarray,
        config: DDPGfDConfig,
        seed: int,
    ):
        self.config = config
        torch.manual_seed(seed)
        self.actor = DeterministicActor(obs_dim, act_dim, low, high, config.hidden_sizes)
        self.critic = QNetwork(obs_dim, act_dim, config.hidden_sizes)
        self.actor_target = copy.deepcopy(self.actor)
        self.critic_target = copy.deepcopy(self.critic)
        self.actor_optimizer = torch.optim.Adam(
            self.actor.parameters(), lr=config.actor_learning_rate
        )
        self.critic_optimizer = torch.optim.Adam(
            self.critic.parameters(), lr=config.critic_learning_rate
        )

    MODULES = (
        "actor",
        "critic",
        "actor_target",
        "critic_target",
        "actor_optimizer",
        "critic_optimizer",
    )

    def state_dict(self) -> dict:
        return {name: getattr(self, name).state_dict() for name in self.MODULES}

    def load_state_dict(self, state: dict) -> None:
        for name in self.MODULES:
            getattr(self, name).load_state_dict(state[name])

    @torch.no_grad()
    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.actor(torch.as_tensor(obs, dtype=torch.float32)[None])[0].numpy()

    def update(self, batch: PrioritizedBatch) -> tuple[dict[str, float], np.ndarray]:
        """One gradient step of critic and actor; returns losses and new priorities."""
        cfg = self.config
        with torch.no_grad():
            next_q = self.critic_target(
                batch.next_observations, self.actor_target(batch.next_observations)
            )
            y_1 = batch.rewards + cfg.gamma * (1.0 - batch.terminated) * next_q
            n_next = batch.n_step_next_observations
            y_n = n_step_target(
                batch.n_step_returns,
                batch.n_step_discounts,
                self.critic_target(n_next, self.actor_target(n_next)),
            )

        actions = batch.actions.clone().requires_grad_(True)
        q = self.critic(batch.observations, actions)
        # |grad_a Q(s_i, a_i)| per transition, for its priority (Vecerik et al., Sec. 4)
        (action_gradients,) = torch.autograd.grad(q.sum(), actions, retain_graph=True)
        td_1 = y_1 - q
        critic_loss = (
            (batch.weights * td_1.pow(2)).mean()
            + cfg.lambda_n_step * (batch.weights * (y_n - q).pow(2)).mean()
            + cfg.l2_coef * l2_penalty(self.critic)
        )
        self.critic_optimizer.zero_grad()
        critic_loss.backward()
        self.critic_optimizer.step()

        # importance weights correct the critic's TD regression only, as in Schaul et al.
        with frozen(self.critic):  # the actor step needs dQ/da only
            actor_loss = -self.critic(
                batch.observations, self.actor(batch.observations)
            ).mean() + cfg.l2_coef * l2_penalty(self.actor)
        self.actor_optimizer.zero_grad()
        actor_loss.backward()
        self.actor_optimizer.step()

        soft_update(self.critic_target, self.critic, cfg.tau)
        soft_update(self.actor_target, self.actor, cfg.tau)
        priorities = transition_priorities(
            td_1.detach().numpy(), action_gradients.numpy(), batch.is_demo, cfg
        )
        return {"critic_loss": critic_loss.item(), "actor_loss": actor_loss.item()}, priorities


def demo_transitions(demos: DemoSet) -> dict[str, np.ndarray]:
    """The demonstrations as transitions; DDPGfD needs rewards and next states, not just (s, a)."""
    missing = [
        name
        for name in ("rewards", "next_observations", "terminated", "truncated")
        if getattr(demos, name, None) is None
    ]
    if missing:
        raise ValueError(
            f"DDPGfD needs demonstration transitions but the file lacks {missing}; "
            "regenerate it with `python -m replicate demos`"
        )
    return {
        "observations": demos.observations,
        "actions": demos.actions,
        "rewards": demos.rewards,
        "next_observations": demos.next_observations,
        "terminated": demos.terminated,
        "episode_end": np.logical_or(demos.terminated, demos.truncated),
    }


@register("ddpgfd", DDPGfDConfig, needs_demos=True)
def train(ctx: TrainContext, config: DDPGfDConfig) -> PrioritizedReplayBuffer:
    """DDPGfD (Vecerik et al. 2017): DDPG with demonstrations kept in prioritized replay."""
    if ctx.demos is None:
        raise ValueError("DDPGfD needs demonstrations")
    with flush_denormals(config.flush_denormals):
        return _train(ctx, config)


def _train(ctx: TrainContext, config: DDPGfDConfig) -> PrioritizedReplayBuffer:
    torch.set_num_threads(config.torch_threads)
    env = make_env(ctx.env_id, seed=ctx.seed)
    eval_env = make_env(ctx.env_id, seed=ctx.seed + EVAL_SEED_OFFSET)
    obs_dim, act_dim = env.observation_space.shape[0], env.action_space.shape[0]
    low, high = env.action_space.low, env.action_space.high
    agent = DDPGfDAgent(obs_dim, act_dim, low, high, config, ctx.seed)

    demos = demo_transitions(ctx.demos)
    n_demo = len(demos["observations"])
    buffer = PrioritizedReplayBuffer(
        obs_dim, act_dim, n_demo + min(config.buffer_size, ctx.total_steps), config.priority_alpha
    )
    buffer.add_demonstrations(**demos)
    rng = np.random.default_rng(ctx.seed)
    noise_std = config.exploration_noise * (high - low) / 2.0

    run = OneRunCheckpoints(ctx, env, eval_env)
    resumed = run.resume()
    if resumed is None:
        start = 1
        run.evaluate(0, agent.act)
        obs, _ = env.reset(seed=ctx.seed)
    else:  # taken where an episode had just ended: see baselines.common.checkpoint
        start = resumed["step"] + 1
        agent.load_state_dict(resumed["agent"])
        buffer.load_state_dict(resumed["buffer"])
        rng = resumed["rng"]
        obs, _ = env.reset()

    for step in range(start, ctx.total_steps + 1):
        action = np.clip(agent.act(obs) + noise_std * rng.standard_normal(act_dim), low, high)
        next_obs, reward, terminated, truncated, _ = env.step(action.astype(np.float32))
        buffer.add(obs, action, reward, next_obs, terminated, truncated)
        obs = next_obs

        if step >= config.learning_starts:
            beta = config.priority_beta0 + (1.0 - config.priority_beta0) * step / ctx.total_steps
            for _ in range(config.gradient_steps):
                batch = buffer.sample(config.batch_size, beta, config.n_step, config.gamma, rng)
                losses, priorities = agent.update(batch)
                buffer.update_priorities(batch.indices, priorities)
            if not np.isfinite(losses["critic_loss"]):
                raise FloatingPointError(f"DDPGfD diverged at step {step}: losses {losses}")

        if step % ctx.eval_interval == 0 or step == ctx.total_steps:
            run.evaluate(step, agent.act)
        ctx.on_steps(1)
        if terminated or truncated:
            run.at_episode_end(
                step,
                lambda: {"agent": agent.state_dict(), "buffer": buffer.state_dict(), "rng": rng},
            )
            obs, _ = env.reset()
    env.close()
    eval_env.close()
    return buffer
