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

import contextlib
import copy
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch.nn import functional as F

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.checkpoint import (
    CheckpointDeviceError,
    due,
    env_rng_state,
    load_checkpoint,
    restore_env_rng,
    save_checkpoint,
    stop_if_past,
)
from baselines.common.context import EvalPoint, TrainContext
from baselines.common.device import GraphedStep, make_adam
from baselines.common.evaluation import EVAL_SEED_OFFSET, TrainingReturns, evaluate
from baselines.common.networks import QNetwork, TanhGaussianPolicy, VNetwork, soft_update
from baselines.common.random_start import random_start_action
from baselines.registry import register
from envs import make_env


@dataclass
class SACConfig:
    """Hyperparameters; defaults are Table 1 of Haarnoja et al. 2018 (arXiv:1801.01290, App. D)."""

    learning_rate: float = 3e-4
    batch_size: int = 256
    hidden_sizes: tuple[int, ...] = (256, 256)
    buffer_size: int = 1_000_000
    gamma: float = 0.99
    tau: float = 0.005  # target smoothing coefficient for V'
    reward_scale: float = 5.0  # Hopper, Walker2d, HalfCheetah and Ant all use 5 in the SAC paper
    learning_starts: int = 1000  # transitions collected by the initial policy before updates
    # uniform-random actions before the policy acts (the SAC authors' code: 1,000 or
    # 10,000); 0, the default, is kept out of a run's address (replicate/runner.py)
    random_start_steps: int = 0
    gradient_steps: int = 1  # per env step
    torch_threads: int = 1  # one run per core is how the harness schedules runs

    def __post_init__(self) -> None:
        self.hidden_sizes = tuple(int(w) for w in self.hidden_sizes)
        if self.batch_size <= 0 or self.buffer_size <= 0 or self.gradient_steps < 1:
            raise ValueError("batch_size, buffer_size and gradient_steps must be positive")


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


@contextlib.contextmanager
def frozen(*modules: torch.nn.Module) -> Iterator[None]:
    """Build the graph through ``modules`` without asking for their weight gradients."""
    params = [p for m in modules for p in m.parameters()]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)


class PolicyActor:
    """Acting for an agent that holds a tanh-Gaussian ``policy``, its ``noise`` generator and
    a ``device``: one observation in, one action out (sampled, or the deterministic one)."""

    policy: TanhGaussianPolicy
    noise: torch.Generator
    device: torch.device

    @torch.no_grad()
    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        obs_t = torch.as_tensor(obs, dtype=torch.float32, device=self.device).unsqueeze(0)
        if deterministic:
            action = self.policy.deterministic(obs_t)
        else:
            action, _ = self.policy.sample(obs_t, self.noise)
        return action.squeeze(0).cpu().numpy()


class SACAgent(PolicyActor):
    """The five networks, their optimisers, and one gradient step of SAC."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        config: SACConfig,
        seed: int,
        device: str = "cpu",
        cuda_graphs: bool = True,
    ):
        self.config = config
        self.device = torch.device(device)
        # Weights come from this seed alone, so SAC and DRL-EG with one seed start identical.
        torch.manual_seed(seed)
        hidden = config.hidden_sizes
        self.q1 = QNetwork(obs_dim, act_dim, hidden).to(self.device)
        self.q2 = QNetwork(obs_dim, act_dim, hidden).to(self.device)
        self.v = VNetwork(obs_dim, hidden).to(self.device)
        self.v_target = copy.deepcopy(self.v)
        self.policy = TanhGaussianPolicy(obs_dim, act_dim, action_low, action_high, hidden).to(
            self.device
        )
        lr = config.learning_rate
        self.q_optimizer = make_adam(
            [*self.q1.parameters(), *self.q2.parameters()], lr, self.device, fused_on_cpu=False
        )
        self.v_optimizer = make_adam(self.v.parameters(), lr, self.device, fused_on_cpu=False)
        self.policy_optimizer = make_adam(
            self.policy.parameters(), lr, self.device, fused_on_cpu=False
        )
        self.noise = torch.Generator(device=self.device).manual_seed(seed + 1)
        self.gradient_step = GraphedStep(self._gradient_step, self.device, cuda_graphs)

    def state_dict(self) -> dict[str, Any]:
        """Networks, optimisers and the exploration noise stream: all a resume needs."""
        modules = (
            "q1",
            "q2",
            "v",
            "v_target",
            "policy",
            "q_optimizer",
            "v_optimizer",
            "policy_optimizer",
        )
        state = {name: getattr(self, name).state_dict() for name in modules}
        state["noise"] = self.noise.get_state()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for name, value in state.items():
            if name == "noise":
                self.noise.set_state(value)
            else:
                getattr(self, name).load_state_dict(value)

    def update(self, batch: Batch) -> dict[str, torch.Tensor]:
        """One gradient step on ``batch``. The losses come back as 0-d tensors: reading one
        waits for the GPU, so the training loop reads them seldom."""
        noise = torch.randn(batch.actions.shape, generator=self.noise, device=self.device)
        return self.gradient_step(
            obs=batch.observations,
            actions=batch.actions,
            rewards=batch.rewards,
            next_obs=batch.next_observations,
            terminated=batch.terminated,
            noise=noise,
        )

    def _gradient_step(
        self,
        obs: torch.Tensor,
        actions: torch.Tensor,
        rewards: torch.Tensor,
        next_obs: torch.Tensor,
        terminated: torch.Tensor,
        noise: torch.Tensor,
    ) -> dict[str, torch.Tensor]:
        cfg = self.config
        # Soft Q-functions regress on r + gamma V'(s') (eq. 15).
        with torch.no_grad():
            y_q = q_target(
                rewards, terminated, self.v_target(next_obs), cfg.gamma, cfg.reward_scale
            )
        q_loss = 0.5 * F.mse_loss(self.q1(obs, actions), y_q) + 0.5 * F.mse_loss(
            self.q2(obs, actions), y_q
        )
        self.q_optimizer.zero_grad()
        q_loss.backward()
        self.q_optimizer.step()

        # V regresses on the soft value of a fresh policy action (eq. 15); the policy
        # minimises the KL to the exponentiated Q through the reparameterisation (eq. 13-14).
        new_actions, log_prob = self.policy.sample(obs, noise=noise)
        with frozen(self.q1, self.q2):  # the policy step needs dQ/da, not Q's weight gradients
            q_new = torch.min(self.q1(obs, new_actions), self.q2(obs, new_actions))
        v_loss = 0.5 * F.mse_loss(self.v(obs), v_target(q_new, log_prob).detach())
        policy_loss = (log_prob - q_new).mean()

        self.v_optimizer.zero_grad()
        v_loss.backward()
        self.v_optimizer.step()
        self.policy_optimizer.zero_grad()
        policy_loss.backward()
        self.policy_optimizer.step()

        soft_update(self.v_target, self.v, cfg.tau)
        return {
            "q_loss": q_loss.detach(),
            "v_loss": v_loss.detach(),
            "policy_loss": policy_loss.detach(),
            "entropy": -log_prob.detach().mean(),
        }


class PolicyExplorer:
    """Chooses the executed action and may see each evaluation. SAC samples its policy;
    DRL-EG's explorer may hand the step to its guider."""

    def __init__(self, agent: SACAgent):
        self.agent = agent

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, bool]:
        """The action to execute and whether a guider chose it."""
        return self.agent.act(obs), False

    def after_eval(self, mean_return: float) -> bool | None:
        """See an evaluation's mean return; report a gate state if there is one."""
        return None

    def episode_start(self) -> None:
        """Called after every env reset, before the episode's first ``choose`` (JSRL counts
        the steps of an episode from here)."""

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        pass


DIVERGENCE_CHECK_INTERVAL = 100  # env steps between looks at the critic loss on a GPU


def run_off_policy(
    ctx: TrainContext, agent: SACAgent, explorer: PolicyExplorer, buffer: ReplayBuffer | None = None
) -> ReplayBuffer:
    """The SAC training loop, shared with DRL-EG (Algorithm 1 of the paper).

    The executed action is what goes in the buffer, guided or not; the buffer is returned.
    ``buffer`` replaces the empty one the loop would make (IBRL preloads demonstrations,
    RLPD samples half of each batch from them). With ``ctx.checkpoint_path`` set, the loop
    checkpoints at episode ends and resumes from a checkpoint it finds there.
    """
    cfg = agent.config
    torch.set_num_threads(cfg.torch_threads)
    env = make_env(ctx.env_id, seed=ctx.seed)
    eval_env = make_env(ctx.env_id, seed=ctx.seed + EVAL_SEED_OFFSET)
    obs_dim, act_dim = env.observation_space.shape[0], env.action_space.shape[0]
    if buffer is None:
        buffer = ReplayBuffer(obs_dim, act_dim, min(cfg.buffer_size, ctx.total_steps))
    batch_rng = np.random.default_rng(ctx.seed)
    curve: list[EvalPoint] = []
    best_return = -np.inf
    training = TrainingReturns()

    def evaluate_and_record(step: int, guided_steps: int, steps_since: int) -> None:
        nonlocal best_return
        returns = evaluate(eval_env, lambda o: agent.act(o, deterministic=True), ctx.eval_episodes)
        gate = explorer.after_eval(float(np.mean(returns)))
        fraction = guided_steps / steps_since if steps_since else float("nan")
        train_return = float(training.take()[0])
        point = EvalPoint(step, tuple(returns), fraction, gate, train_return)
        curve.append(point)
        ctx.on_eval(point)
        if ctx.best_policy_path is not None and point.mean_return > best_return:
            best_return = point.mean_return
            save_checkpoint(
                ctx.best_policy_path,
                {"policy": agent.policy.state_dict(), "step": step, "mean_return": best_return},
            )

    def save(step: int) -> None:
        save_checkpoint(
            ctx.checkpoint_path,
            {
                "step": step,
                "device": agent.device.type,
                "agent": agent.state_dict(),
                "explorer": explorer.state_dict(),
                "buffer": buffer.state_dict(),
                "batch_rng": batch_rng,
                "curve": curve,
                "counters": (guided_steps, steps_since_eval, best_return),
                "training_returns": training.state_dict(),
                "env_rng": env_rng_state(env),
                "eval_env_rng": env_rng_state(eval_env),
            },
        )

    resumed = load_checkpoint(ctx.checkpoint_path)
    if resumed is None:
        start = 1
        evaluate_and_record(0, 0, 0)
        obs, _ = env.reset(seed=ctx.seed)
        explorer.episode_start()
        guided_steps = steps_since_eval = 0
    else:
        start = resumed["step"] + 1
        saved_on = resumed.get("device", "cpu")
        if saved_on != agent.device.type:  # the noise streams of CPU and CUDA differ in kind
            raise CheckpointDeviceError(
                f"the checkpoint at {ctx.checkpoint_path} was made on {saved_on}; "
                f"resume it with --device {saved_on}, or delete it to start over on "
                f"{agent.device.type}"
            )
        agent.load_state_dict(resumed["agent"])
        explorer.load_state_dict(resumed["explorer"])
        buffer.load_state_dict(resumed["buffer"])
        batch_rng = resumed["batch_rng"]
        guided_steps, steps_since_eval, best_return = resumed["counters"]
        # taken where an episode had just ended
        training.load_state_dict(resumed.get("training_returns"), between_episodes=True)
        restore_env_rng(env, resumed["env_rng"])
        restore_env_rng(eval_env, resumed["eval_env_rng"])
        ctx.on_resume(resumed["step"])
        for point in resumed["curve"]:
            curve.append(point)
            ctx.on_eval(point)
        ctx.on_steps(resumed["step"])
        obs, _ = env.reset()  # checkpoints are taken where an episode has just ended
        explorer.episode_start()
    last_checkpoint = start - 1

    low, high = env.action_space.low, env.action_space.high
    for step in range(start, ctx.total_steps + 1):
        if step <= cfg.random_start_steps:
            action, guided = random_start_action(ctx.seed, step, low, high), False
        else:
            action, guided = explorer.choose(obs)
        next_obs, reward, terminated, truncated, _ = env.step(action)
        buffer.add(obs, action, reward, next_obs, terminated)
        obs = next_obs
        training.add(reward, terminated or truncated)
        guided_steps += guided
        steps_since_eval += 1

        if step >= cfg.learning_starts:
            for _ in range(cfg.gradient_steps):
                losses = agent.update(buffer.sample(cfg.batch_size, batch_rng))
            # on a GPU reading a loss stalls the CPU until the update is done, so that the
            # env step cannot overlap it: there the loss is read every hundred steps
            look = (
                agent.device.type == "cpu"
                or step % DIVERGENCE_CHECK_INTERVAL == 0
                or step == ctx.total_steps
            )
            if look and not math.isfinite(losses["q_loss"]):
                raise FloatingPointError(
                    f"SAC diverged at step {step}: losses "
                    f"{ {name: float(v) for name, v in losses.items()} }"
                )

        if step % ctx.eval_interval == 0 or step == ctx.total_steps:
            evaluate_and_record(step, guided_steps, steps_since_eval)
            guided_steps = steps_since_eval = 0
        ctx.on_steps(1)
        if terminated or truncated:
            if (
                ctx.checkpoint_path is not None
                and step < ctx.total_steps
                and due(step, last_checkpoint, ctx.checkpoint_interval, ctx.deadline)
            ):
                save(step)
                last_checkpoint = step
                stop_if_past(ctx.deadline, step)
            obs, _ = env.reset()
            explorer.episode_start()
    env.close()
    eval_env.close()
    return buffer


def build_agent(ctx: TrainContext, config: SACConfig) -> SACAgent:
    probe = make_env(ctx.env_id)
    space = probe.action_space
    agent = SACAgent(
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


@register("sac", SACConfig, gpu=True)
def train(ctx: TrainContext, config: SACConfig) -> ReplayBuffer:
    """SAC with a V network (Haarnoja et al. 2018), the paper's baseline and DRL-EG's base."""
    agent = build_agent(ctx, config)
    return run_off_policy(ctx, agent, PolicyExplorer(agent))
