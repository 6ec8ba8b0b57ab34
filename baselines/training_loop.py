"""The training loop of the SAC family's trainer (``baselines.offpolicy``): a seed batch's
N envs stepped together, acting through an explorer, the gradient steps, evaluations,
checkpoints and resume, as a small state object with named steps. It knows the agent only
through its contract (``baselines.contract``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from baselines.common.checkpoint import (
    CheckpointDeviceError,
    due,
    load_checkpoint,
    save_checkpoint,
    stop_if_past,
)
from baselines.common.context import BatchContext, EvalPoint
from baselines.common.evaluation import EVAL_SEED_OFFSET, TrainingReturns
from baselines.common.random_start import random_start_action
from baselines.common.stacked import StackedReplay
from baselines.contract import AgentContract, agent_state, load_agent_state, no_global_draws
from envs import make_env
from envs.vector import EnvBatch


def action_space(env_id: str) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Observation size, action size and the action box of ``env_id``."""
    probe = make_env(env_id)
    obs_dim, space = probe.observation_space.shape[0], probe.action_space
    probe.close()
    return obs_dim, space.shape[0], space.low, space.high


class PolicyExplorer:
    """Chooses each member's executed action and sees each evaluation. SAC samples its
    policy; DRL-EG's, IBRL's and JSRL's explorers may hand a member's step to a guide."""

    def __init__(self, agent: AgentContract):
        self.agent = agent

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each member's action to execute, and whether a guide chose it."""
        return self.agent.act(obs), np.zeros(len(obs), dtype=bool)

    def after_eval(self, k: int, mean_return: float) -> bool | None:
        """Member k's evaluation; a gate state to record, where the explorer has one."""
        return None

    def episode_start(self, started: np.ndarray) -> None:
        """The members in ``started`` begin an episode (JSRL counts its steps from here)."""

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        pass


def evaluate_members(
    envs: EnvBatch, act: Callable[[np.ndarray], np.ndarray], episodes: int, members: np.ndarray
) -> list[list[float]]:
    """``episodes`` deterministic episodes for each member in ``members``, its env stepped
    only while it still needs one (as ``baselines.common.evaluation.evaluate`` does)."""
    returns: list[list[float]] = [[] for _ in range(envs.n)]
    totals = np.zeros(envs.n)
    running = np.asarray(members, dtype=bool).copy()
    if not running.any():
        return returns
    obs = envs.reset(which=running)
    while running.any():
        more = running & np.array([len(r) + 1 < episodes for r in returns])
        result = envs.step(act(obs), active=running, reset_done=more)
        for k in np.flatnonzero(running):
            totals[k] += result.rewards[k]
            if result.terminated[k] or result.truncated[k]:
                returns[k].append(float(totals[k]))
                totals[k] = 0.0
                running[k] = len(returns[k]) < episodes
        obs = result.obs
    return returns


DIVERGENCE_CHECK_INTERVAL = 100  # env steps between looks at the losses on a GPU


def losses_due(device_type: str, step: int, total_steps: int) -> bool:
    """Whether this step's losses are read: every step on CPU; on a GPU every
    ``DIVERGENCE_CHECK_INTERVAL`` steps (reading them waits for the device)."""
    return device_type == "cpu" or step % DIVERGENCE_CHECK_INTERVAL == 0 or step == total_steps


def run_off_policy(
    bctx: BatchContext, agent: AgentContract, explorer: PolicyExplorer
) -> StackedReplay:
    """The training loop of the SAC family (Algorithm 1 of the paper for DRL-EG): N envs,
    N replays, N curves, one update of every member per env step; the replay is returned.
    The executed action is what goes in the replay, guided or not."""
    return OffPolicyRun(bctx, agent, explorer).run()


class OffPolicyRun:
    """One seed batch's training, in named steps: ``begin`` afresh or ``resume`` from the
    batch checkpoint, then for every env step ``act`` (the explorer's choice, or the seed's
    random start), ``step_envs``, ``learn`` (the gradient steps, and a look at the losses)
    and, when due, ``evaluate`` and ``save``. A member whose action or losses are not
    finite ``fail``s alone."""

    def __init__(self, bctx: BatchContext, agent: AgentContract, explorer: PolicyExplorer):
        self.bctx, self.agent, self.explorer = bctx, agent, explorer
        self.cfg = cfg = agent.config
        torch.set_num_threads(cfg.torch_threads)
        self.env_id, self.total_steps = bctx.shared("env_id"), bctx.shared("total_steps")
        self.eval_interval = bctx.shared("eval_interval")
        self.eval_episodes = bctx.shared("eval_episodes")
        self.seeds, self.n = bctx.seeds, len(bctx.members)
        n = self.n
        self.envs = EnvBatch(self.env_id, self.seeds, bctx.env_workers)
        eval_seeds = [s + EVAL_SEED_OFFSET for s in self.seeds]
        self.eval_envs = EnvBatch(self.env_id, eval_seeds, bctx.env_workers)
        capacity = min(cfg.buffer_size, self.total_steps)
        agent.buffer = agent.make_replay(n, self.envs.obs_dim, capacity)
        self.buffer = agent.buffer
        self.batch_rngs = [np.random.default_rng(seed) for seed in self.seeds]
        self.curves: list[list[EvalPoint]] = [[] for _ in range(n)]
        self.alive = np.ones(n, dtype=bool)
        self.failures: dict[int, str] = {}
        self.guided_steps = np.zeros(n, dtype=np.int64)
        self.training = TrainingReturns(n)
        self.steps_since_eval = 0
        self.best_returns = np.full(n, -np.inf)  # for members that keep their best policy
        self.obs = np.zeros(0)
        self.idle_action = np.zeros(agent.act_dim, dtype=np.float32)
        self.low = self.high = np.zeros(0)  # the action box, read when the loop starts

    def run(self) -> StackedReplay:
        bctx, total_steps = self.bctx, self.total_steps
        try:
            resumed = load_checkpoint(bctx.checkpoint_path)
            start = self.begin() if resumed is None else self.resume(resumed)
            last_checkpoint = start - 1
            _, _, self.low, self.high = action_space(self.env_id)
            for step in range(start, total_steps + 1):
                actions, guided = self.act(step)
                self.step_envs(actions, guided)
                if step >= self.cfg.learning_starts:
                    self.learn(step)
                if step % self.eval_interval == 0 or step == total_steps:
                    with no_global_draws("the evaluation"):
                        self.evaluate(step)
                    self.guided_steps[:] = 0
                    self.steps_since_eval = 0
                bctx.on_steps(int(self.alive.sum()))
                if not self.alive.any():
                    break
                if (
                    bctx.checkpoint_path is not None
                    and step < total_steps
                    and due(step, last_checkpoint, bctx.checkpoint_interval, bctx.deadline)
                ):
                    self.save(step)
                    last_checkpoint = step
                    stop_if_past(bctx.deadline, step)
        finally:
            self.envs.close()
            self.eval_envs.close()
        return self.buffer

    def begin(self) -> int:
        """A fresh start: the untrained policies' evaluation, the envs reset; the first step."""
        self.evaluate(0)
        self.obs = self.envs.reset(seeds=self.seeds)
        self.explorer.episode_start(np.ones(self.n, dtype=bool))
        return 1

    def resume(self, resumed: dict[str, Any]) -> int:
        """Everything as the checkpoint left it (the envs replayed to their states); the step
        to go on from."""
        bctx, agent = self.bctx, self.agent
        if resumed["device"] != agent.device.type:
            raise CheckpointDeviceError(
                f"the batch checkpoint at {bctx.checkpoint_path} was made on "
                f"{resumed['device']}; resume it with --device {resumed['device']}, or "
                f"delete it to start over on {agent.device.type}"
            )
        if resumed["seeds"] != self.seeds:
            raise ValueError(
                f"the checkpoint at {bctx.checkpoint_path} holds seeds "
                f"{resumed['seeds']}, not {self.seeds}"
            )
        load_agent_state(agent, resumed["agent"])
        self.explorer.load_state_dict(resumed["explorer"])
        self.buffer.load_state_dict(resumed["buffer"])
        self.batch_rngs = resumed["batch_rngs"]
        self.alive[:] = resumed["alive"]
        for k, reason in resumed["failures"].items():  # failed before the checkpoint
            self.fail(k, reason, self.total_steps)
        self.guided_steps[:] = resumed["guided_steps"]
        self.training.load_state_dict(resumed.get("training_returns"))
        self.steps_since_eval = resumed["steps_since_eval"]
        self.obs = resumed["obs"]
        replayed = self.envs.restore(resumed["envs"])
        for k in np.flatnonzero(self.alive):
            if replayed[k] is None or not np.array_equal(replayed[k], self.obs[k]):
                raise RuntimeError(
                    f"member {k}'s env did not come back to its "
                    "checkpointed state on replay (is it deterministic?)"
                )
        self.eval_envs.restore(resumed["eval_envs"])
        bctx.on_resume(resumed["step"])
        for k in range(self.n):
            for point in resumed["curves"][k]:
                self.curves[k].append(point)
                bctx.members[k].on_eval(point)
                self.best_returns[k] = max(self.best_returns[k], point.mean_return)
        bctx.on_steps(resumed["step"] * int(self.alive.sum()))
        return resumed["step"] + 1

    def act(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        """Each member's action and whether a guide chose it; failed members idle."""
        if step <= self.cfg.random_start_steps:  # each member draws its seed's actions
            actions = np.stack(
                [random_start_action(seed, step, self.low, self.high) for seed in self.seeds]
            )
            guided = np.zeros(self.n, dtype=bool)
        else:
            acting = (
                f"{type(self.explorer).__name__}'s choice of {type(self.agent).__name__}'s actions"
            )
            with no_global_draws(acting):
                actions, guided = self.explorer.choose(self.obs)
        # a member whose networks diverged between looks at its losses (on a GPU) fails
        # here, alone, before its NaN action reaches its env and the batch's shared
        # lookups (a KD-tree refuses a NaN state for every member)
        for k in np.flatnonzero(self.alive & ~np.isfinite(actions).all(axis=1)):
            self.fail(
                k, f"diverged at step {step}: a non-finite action", self.total_steps - step + 1
            )
        actions[~self.alive] = self.idle_action
        return actions, guided

    def step_envs(self, actions: np.ndarray, guided: np.ndarray) -> None:
        """One step of every live member's env; the transition goes in its replay."""
        result = self.envs.step(actions, active=self.alive)
        self.buffer.add(self.obs, actions, result.rewards, result.next_obs, result.terminated)
        self.obs = result.obs
        ended = (result.terminated | result.truncated) & self.alive
        self.training.add(result.rewards, ended)
        if ended.any():
            self.explorer.episode_start(ended)
        self.guided_steps += guided & self.alive
        self.steps_since_eval += 1

    def learn(self, step: int) -> None:
        """The gradient steps of every member; a look at the losses where one is due."""
        for _ in range(self.cfg.gradient_steps):
            losses = self.agent.update(self.batch_rngs)
        if losses_due(self.agent.device.type, step, self.total_steps):
            q_loss = losses["q_loss"].cpu().numpy()
            for k in np.flatnonzero(self.alive & ~np.isfinite(q_loss)):
                self.fail(
                    k,
                    f"diverged at step {step}: losses "
                    f"{ {name: float(v[k]) for name, v in losses.items()} }",
                    self.total_steps - step + 1,
                )

    def fail(self, k: int, reason: str, steps_left: int) -> None:
        self.alive[k] = False
        self.failures[k] = reason
        self.bctx.on_member_failed(k, reason)
        self.bctx.on_steps(steps_left)  # a failed member's steps count as done for the progress

    def evaluate(self, step: int) -> None:
        """Every live member's deterministic episodes, recorded as its curve's next point;
        a member that keeps its best policy saves it when this one is its best."""
        agent, bctx = self.agent, self.bctx
        returns = evaluate_members(
            self.eval_envs, agent.act_deterministic, self.eval_episodes, self.alive
        )
        train_returns = self.training.take()
        for k in np.flatnonzero(self.alive):
            gate = self.explorer.after_eval(k, float(np.mean(returns[k])))
            since = self.steps_since_eval
            fraction = self.guided_steps[k] / since if since else float("nan")
            point = EvalPoint(
                step, tuple(returns[k]), float(fraction), gate, float(train_returns[k])
            )
            self.curves[k].append(point)
            bctx.members[k].on_eval(point)
            keep = bctx.members[k].best_policy_path
            if keep is not None and point.mean_return > self.best_returns[k]:
                self.best_returns[k] = point.mean_return
                save_checkpoint(
                    keep,
                    {
                        "policy": agent.policy.member_policy(k).state_dict(),
                        "step": step,
                        "mean_return": point.mean_return,
                    },
                )

    def save(self, step: int) -> None:
        """The whole batch's checkpoint, mid-episode too (the envs replay their actions)."""
        save_checkpoint(
            self.bctx.checkpoint_path,
            {
                "step": step,
                "device": self.agent.device.type,
                "seeds": self.seeds,
                "agent": agent_state(self.agent),
                "explorer": self.explorer.state_dict(),
                "buffer": self.buffer.state_dict(),
                "batch_rngs": self.batch_rngs,
                "curves": self.curves,
                "alive": self.alive.copy(),
                "failures": dict(self.failures),
                "obs": self.obs.copy(),
                "guided_steps": self.guided_steps.copy(),
                "training_returns": self.training.state_dict(),
                "steps_since_eval": self.steps_since_eval,
                "envs": self.envs.snapshot(),
                "eval_envs": self.eval_envs.snapshot(),
            },
        )
