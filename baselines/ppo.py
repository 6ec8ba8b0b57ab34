"""Proximal Policy Optimization (Schulman et al. 2017, arXiv:1707.06347), MuJoCo settings.

Collect ``rollout_steps`` transitions with a Gaussian policy, compute advantages with GAE,
then run ``epochs`` passes of minibatch Adam on the clipped surrogate

    L = -E[min(rho * A, clip(rho, 1 - eps, 1 + eps) * A)],  rho = pi(a|s) / pi_old(a|s)

plus a value regression. Observations are normalised by running statistics and rewards
by the running std of the discounted return, as the reference implementation (OpenAI
baselines' ppo2 with VecNormalize) does on MuJoCo. A time-limit truncation ends the GAE
chain but still bootstraps from V(s'); only termination drops V(s').
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from baselines.common.checkpoint import OneRunCheckpoints
from baselines.common.context import TrainContext
from baselines.common.evaluation import EVAL_SEED_OFFSET
from baselines.common.networks import mlp
from baselines.common.normalization import ReturnScaler, RunningMeanStd
from baselines.registry import register
from envs import make_env


@dataclass
class PPOConfig:
    """Defaults: Table 3 of Schulman et al. 2017 (horizon 2048, Adam 3e-4, 10 epochs,
    minibatch 64, gamma 0.99, GAE lambda 0.95, clip 0.2, 2x64 tanh networks); value
    coefficient, gradient clipping at 0.5, linear learning-rate decay and observation and
    reward normalisation clipped at 10 are baselines' ppo2 MuJoCo defaults."""

    learning_rate: float = 3e-4
    anneal_learning_rate: bool = True
    rollout_steps: int = 2048
    epochs: int = 10
    minibatch_size: int = 64
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_coef: float = 0.2
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    max_grad_norm: float = 0.5
    hidden_sizes: tuple[int, ...] = (64, 64)
    normalize_observations: bool = True
    normalize_rewards: bool = True
    clip_normalized: float = 10.0
    torch_threads: int = 1

    def __post_init__(self) -> None:
        self.hidden_sizes = tuple(int(w) for w in self.hidden_sizes)
        if self.rollout_steps <= 0 or self.minibatch_size <= 0 or self.epochs <= 0:
            raise ValueError("rollout_steps, minibatch_size and epochs must be positive")


def gae_advantages(
    rewards: np.ndarray,
    values: np.ndarray,
    next_values: np.ndarray,
    terminated: np.ndarray,
    episode_over: np.ndarray,
    gamma: float,
    lam: float,
) -> np.ndarray:
    """Generalised advantage estimation over one rollout.

    delta_t = r_t + gamma * (1 - terminated_t) * V(s'_t) - V(s_t)
    A_t = delta_t + gamma * lam * (1 - episode_over_t) * A_{t+1}

    ``next_values`` holds V of each transition's real next state (the final state at a
    truncation), so a time limit bootstraps while it still cuts the chain.
    """
    advantages = np.zeros_like(rewards, dtype=np.float64)
    running = 0.0
    for t in reversed(range(len(rewards))):
        delta = rewards[t] + gamma * (1.0 - terminated[t]) * next_values[t] - values[t]
        running = delta + gamma * lam * (1.0 - episode_over[t]) * running
        advantages[t] = running
    return advantages


def clipped_surrogate_loss(
    new_log_prob: torch.Tensor,
    old_log_prob: torch.Tensor,
    advantages: torch.Tensor,
    clip_coef: float,
) -> torch.Tensor:
    """-E[min(rho A, clip(rho, 1-eps, 1+eps) A)]."""
    ratio = torch.exp(new_log_prob - old_log_prob)
    clipped = torch.clamp(ratio, 1.0 - clip_coef, 1.0 + clip_coef)
    return -torch.min(ratio * advantages, clipped * advantages).mean()


def normal_log_prob(value: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """log N(value; mean, std^2) per dimension, the very operations of
    ``torch.distributions.Normal.log_prob`` without building a distribution each env step."""
    return -((value - mean) ** 2) / (2 * std**2) - std.log() - math.log(math.sqrt(2 * math.pi))


def _orthogonal_init(net: nn.Sequential, output_gain: float) -> None:
    linears = [m for m in net if isinstance(m, nn.Linear)]
    for i, layer in enumerate(linears):
        nn.init.orthogonal_(
            layer.weight, gain=output_gain if i == len(linears) - 1 else math.sqrt(2)
        )
        nn.init.zeros_(layer.bias)


class PPOAgent(nn.Module):
    """Gaussian policy (state-independent log-std), value network, normalisers, optimiser."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        config: PPOConfig,
        seed: int,
    ):
        super().__init__()
        self.config = config
        torch.manual_seed(seed)
        self.actor_mean = mlp(obs_dim, act_dim, config.hidden_sizes, nn.Tanh)
        self.critic = mlp(obs_dim, 1, config.hidden_sizes, nn.Tanh)
        _orthogonal_init(self.actor_mean, 0.01)
        _orthogonal_init(self.critic, 1.0)
        self.log_std = nn.Parameter(torch.zeros(act_dim))
        self.optimizer = torch.optim.Adam(
            self.parameters(), lr=config.learning_rate, eps=1e-5, foreach=True
        )
        self.obs_stats = RunningMeanStd((obs_dim,))
        self.action_low, self.action_high = action_low, action_high
        self.noise = torch.Generator().manual_seed(seed + 1)

    def normalize(self, obs: np.ndarray, update: bool = False) -> np.ndarray:
        if not self.config.normalize_observations:
            return np.asarray(obs, dtype=np.float32)
        if update:
            self.obs_stats.update(obs)
        return self.obs_stats.normalize(obs, self.config.clip_normalized)

    def distribution(self, norm_obs: torch.Tensor) -> torch.distributions.Normal:
        # the arguments are valid by construction; checking them costs more than the math
        return torch.distributions.Normal(
            self.actor_mean(norm_obs), self.log_std.exp(), validate_args=False
        )

    def value(self, norm_obs: torch.Tensor) -> torch.Tensor:
        return self.critic(norm_obs).squeeze(-1)

    @torch.no_grad()
    def sample(self, norm_obs: np.ndarray) -> tuple[np.ndarray, float]:
        obs_t = torch.as_tensor(norm_obs).unsqueeze(0)
        mean = self.actor_mean(obs_t)
        std = self.log_std.exp()
        action = mean + std * torch.randn(mean.shape, generator=self.noise)
        log_prob = normal_log_prob(action, mean, std.expand_as(mean)).sum(-1)
        return action.squeeze(0).numpy(), float(log_prob)

    def checkpoint_state(self) -> dict:
        """Weights, optimiser, observation statistics and the sampling stream."""
        return {
            "modules": self.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "obs_stats": dict(self.obs_stats.__dict__),
            "noise": self.noise.get_state(),
        }

    def load_checkpoint_state(self, state: dict) -> None:
        self.load_state_dict(state["modules"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.obs_stats.__dict__.update(state["obs_stats"])
        self.noise.set_state(state["noise"])

    @torch.no_grad()
    def act_deterministic(self, obs: np.ndarray) -> np.ndarray:
        mean = self.actor_mean(torch.as_tensor(self.normalize(obs)).unsqueeze(0)).squeeze(0)
        return np.clip(mean.numpy(), self.action_low, self.action_high)


def build_agent(ctx: TrainContext, config: PPOConfig) -> PPOAgent:
    probe = make_env(ctx.env_id)
    space = probe.action_space
    agent = PPOAgent(
        probe.observation_space.shape[0], space.shape[0], space.low, space.high, config, ctx.seed
    )
    probe.close()
    return agent


def run_ppo(ctx: TrainContext, agent: PPOAgent) -> None:
    """The PPO training loop (shared with PPO+BC, which pre-trains ``agent`` first).

    With ``ctx.checkpoint_path`` set it checkpoints at episode ends, the partly collected
    rollout included, and resumes from a checkpoint it finds there.
    """
    cfg = agent.config
    torch.set_num_threads(cfg.torch_threads)
    env = make_env(ctx.env_id, seed=ctx.seed)
    eval_env = make_env(ctx.env_id, seed=ctx.seed + EVAL_SEED_OFFSET)
    reward_scaler = ReturnScaler(cfg.gamma, cfg.clip_normalized)
    batch_rng = np.random.default_rng(ctx.seed)
    n_rollouts = math.ceil(ctx.total_steps / cfg.rollout_steps)
    names = ("obs", "next_obs", "actions", "log_probs", "rewards", "terminated", "over")
    run = OneRunCheckpoints(ctx, env, eval_env)
    resumed = run.resume()
    if resumed is None:
        run.evaluate(0, agent.act_deterministic)
        raw_obs, _ = env.reset(seed=ctx.seed)
        step, first_rollout, collected = 0, 0, {name: [] for name in names}
    else:  # taken where an episode had just ended: see baselines.common.checkpoint
        agent.load_checkpoint_state(resumed["agent"])
        reward_scaler.stats.__dict__.update(resumed["reward_stats"])
        reward_scaler.discounted = resumed["reward_discounted"]
        batch_rng = resumed["batch_rng"]
        step, first_rollout, collected = resumed["step"], resumed["rollout"], resumed["collected"]
        raw_obs, _ = env.reset()

    for rollout in range(first_rollout, n_rollouts):
        if cfg.anneal_learning_rate:
            for group in agent.optimizer.param_groups:
                group["lr"] = cfg.learning_rate * (1.0 - rollout / n_rollouts)
        horizon = min(cfg.rollout_steps, ctx.total_steps - rollout * cfg.rollout_steps)
        while len(collected["obs"]) < horizon:
            norm_obs = agent.normalize(raw_obs, update=True)
            action, log_prob = agent.sample(norm_obs)
            clipped = np.clip(action, agent.action_low, agent.action_high)
            raw_next, reward, terminated, truncated, _ = env.step(clipped)
            episode_over = terminated or truncated
            for name, value in zip(
                names,
                (
                    norm_obs,
                    agent.normalize(raw_next),
                    action,
                    log_prob,
                    reward_scaler(reward, episode_over) if cfg.normalize_rewards else reward,
                    float(terminated),
                    float(episode_over),
                ),
                strict=True,
            ):
                collected[name].append(value)
            raw_obs = raw_next
            step += 1
            if step % ctx.eval_interval == 0 and step < ctx.total_steps:
                # the final evaluation comes after the last update
                run.evaluate(step, agent.act_deterministic)
            ctx.on_steps(1)
            if episode_over:
                run.at_episode_end(
                    step,
                    lambda: {
                        "rollout": rollout,
                        "collected": collected,
                        "agent": agent.checkpoint_state(),
                        "reward_stats": dict(reward_scaler.stats.__dict__),
                        "reward_discounted": reward_scaler.discounted,
                        "batch_rng": batch_rng,
                    },
                )
                raw_obs, _ = env.reset()

        obs_buf, next_obs_buf, act_buf, logp_buf, rew_buf, term_buf, over_buf = (
            collected[name] for name in names
        )
        collected = {name: [] for name in names}
        obs_t = torch.as_tensor(np.array(obs_buf))
        act_t = torch.as_tensor(np.array(act_buf))
        old_logp_t = torch.as_tensor(np.array(logp_buf, dtype=np.float32))
        with torch.no_grad():
            values = agent.value(obs_t).numpy()
            next_values = agent.value(torch.as_tensor(np.array(next_obs_buf))).numpy()
        advantages = gae_advantages(
            np.array(rew_buf),
            values,
            next_values,
            np.array(term_buf),
            np.array(over_buf),
            cfg.gamma,
            cfg.gae_lambda,
        )
        returns_t = torch.as_tensor((advantages + values).astype(np.float32))
        adv_t = torch.as_tensor(advantages.astype(np.float32))

        for _ in range(cfg.epochs):
            order = batch_rng.permutation(horizon)
            for start in range(0, horizon, cfg.minibatch_size):
                idx = torch.as_tensor(order[start : start + cfg.minibatch_size])
                dist = agent.distribution(obs_t[idx])
                new_logp = dist.log_prob(act_t[idx]).sum(-1)
                mb_adv = adv_t[idx]
                if len(idx) > 1:
                    mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
                policy_loss = clipped_surrogate_loss(
                    new_logp, old_logp_t[idx], mb_adv, cfg.clip_coef
                )
                value_loss = 0.5 * F.mse_loss(agent.value(obs_t[idx]), returns_t[idx])
                entropy = dist.entropy().sum(-1).mean()
                loss = policy_loss + cfg.value_coef * value_loss - cfg.entropy_coef * entropy
                if not torch.isfinite(loss):
                    raise FloatingPointError(f"PPO diverged at step {step}")
                agent.optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), cfg.max_grad_norm, foreach=True)
                agent.optimizer.step()
    run.evaluate(ctx.total_steps, agent.act_deterministic)  # the policy after its last update
    env.close()
    eval_env.close()


@register("ppo", PPOConfig)
def train(ctx: TrainContext, config: PPOConfig) -> None:
    """PPO with the clipped objective and GAE (Schulman et al. 2017), MuJoCo settings."""
    run_ppo(ctx, build_agent(ctx, config))
