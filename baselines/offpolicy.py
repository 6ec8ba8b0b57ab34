"""The one off-policy trainer of the SAC family: N members (a seed batch; one run is N = 1).

The members share algorithm, env, budget and network shapes and differ in seed (DRL-EG
members may also differ in T2 and sigma, which change no shape). Every network is a stack
of N (``baselines.common.stacked``): one batched product per layer serves all members, and
no statistic is shared across them. Member k starts from the weights its seed gives
(``torch.manual_seed(seed)`` before its networks are built, in a fixed order) and on CPU
draws its exploration noise, replay indices and guide noise from streams of its own seed,
so member k's numbers are the same, bit for bit, in any batch of two or more; a batch of one
(a run trained alone) agrees with them to rounding, since the batched kernels round a stack
of one differently.

On a GPU the gradient step of all N members (replay sampling included) is one CUDA graph
replay, and so is the policy's action for all N (not IBRL's: its imitation actions come from
the CPU); there the members draw their noise and replay indices from one device generator
for the batch (GPU curves are not bit-reproducible in any case).

What an agent writes, may override and checkpoints is ``baselines.contract``. The loop
(``run_off_policy``) steps the N envs together; a member whose losses turn NaN or inf fails
alone. Checkpoints hold the whole batch, mid-episode too (the envs replay their actions).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
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
from baselines.common.device import GraphedStep
from baselines.common.evaluation import EVAL_SEED_OFFSET, TrainingReturns
from baselines.common.random_start import random_start_action
from baselines.common.stacked import StackedMLP, StackedPolicy, StackedReplay
from baselines.contract import (
    AgentContract,
    ContractError,
    agent_state,
    check_contract,
    load_agent_state,
    no_global_draws,
)
from envs import make_env
from envs.vector import EnvBatch


@dataclass
class OffPolicyConfig:
    """The settings every member of the SAC family has; each algorithm adds its own."""

    learning_rate: float = 3e-4
    batch_size: int = 256
    hidden_sizes: tuple[int, ...] = (256, 256)
    buffer_size: int = 1_000_000
    gamma: float = 0.99
    tau: float = 0.005  # target smoothing coefficient
    learning_starts: int = 1000  # transitions collected by the initial policy before updates
    # uniform-random actions before the policy acts (the SAC authors' code: 1,000 or
    # 10,000); 0, the default, is kept out of a run's address (replicate/store/runner.py)
    random_start_steps: int = 0
    gradient_steps: int = 1  # per env step
    torch_threads: int = 1  # one process per core is how the harness schedules training
    # keep the policy of the best evaluation so far beside the run (experts); False, the
    # default, is kept out of a run's address
    keep_best_policy: bool = False

    def __post_init__(self) -> None:
        self.hidden_sizes = tuple(int(w) for w in self.hidden_sizes)
        if self.batch_size <= 0 or self.buffer_size <= 0 or self.gradient_steps < 1:
            raise ValueError("batch_size, buffer_size and gradient_steps must be positive")


def action_space(env_id: str) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Observation size, action size and the action box of ``env_id``."""
    probe = make_env(env_id)
    obs_dim, space = probe.observation_space.shape[0], probe.action_space
    probe.close()
    return obs_dim, space.shape[0], space.low, space.high


def seed_device_stream(bctx: BatchContext) -> None:
    """On a GPU, the batch's device stream; called after the members' networks are built,
    since building them reseeds every device."""
    if bctx.device != "cpu":
        torch.cuda.manual_seed(bctx.seeds[0] + 1)


def stack_policies(policies: list, device: torch.device) -> StackedPolicy:
    """The members' tanh-Gaussian policies as one stacked policy."""
    first = policies[0]
    return StackedPolicy(
        StackedMLP.stack([p.trunk for p in policies]), first.action_scale, first.action_bias
    ).to(device)


class OffPolicyAgent(AgentContract):
    """The trainer's side of every SAC-family agent of N members: building in order,
    acting, the noise streams, the replay and the update's plumbing. A subclass writes what
    ``baselines.contract.AgentContract`` asks for; its gradient step is written once, on
    ``[N, B, ...]`` tensors. On CPU member k draws its noise from its own generator (seed +
    1); on a GPU the members draw from the batch's device generator."""

    def __init__(
        self,
        seeds: list[int],
        env_id: str,
        config: OffPolicyConfig,
        device: str = "cpu",
        cuda_graphs: bool = True,
    ):
        obs_dim, low, high = self._begin(seeds, env_id, config, device)
        self.build(obs_dim, low, high)
        self._ready(cuda_graphs)

    def member_noise(self, rows: int, need: np.ndarray | None = None) -> torch.Tensor:
        """``rows`` standard normals (N, rows, act_dim) on the CPU, member k's from its own
        generator; members not in ``need`` draw nothing (their rows stay 0)."""
        noise = torch.zeros((self.members, rows, self.act_dim))
        for k, generator in enumerate(self.generators):
            if need is None or need[k]:
                noise[k] = torch.randn((rows, self.act_dim), generator=generator)
        return noise

    def _begin(
        self, seeds: list[int], env_id: str, config: OffPolicyConfig, device: str
    ) -> tuple[int, np.ndarray, np.ndarray]:
        """What every agent sets first: its config, device, members, action size and their
        noise streams (member k's from seed k + 1); returns the observation size and the
        action box for building the networks."""
        self.config, self.device = config, torch.device(device)
        self.batch_size = config.batch_size
        obs_dim, self.act_dim, low, high = action_space(env_id)
        self.seeds, self.members = list(seeds), len(seeds)
        self.generators = [torch.Generator().manual_seed(seed + 1) for seed in seeds]
        return obs_dim, low, high

    def _ready(self, cuda_graphs: bool) -> None:
        """After the networks and optimisers: the contract checked, then acting and the
        update (CUDA graphs on a GPU)."""
        check_contract(self, cuda_graphs)
        self._act_graph = GraphedStep(self._act_body, self.device, cuda_graphs)
        self.buffer: StackedReplay | None = None
        self._size = torch.zeros((), dtype=torch.long, device=self.device)
        self._step_graphs = {
            kind: GraphedStep(
                functools.partial(self._sample_and_update, kind=kind), self.device, cuda_graphs
            )
            for kind in self.STEP_KINDS
        }

    @property
    def _update_graph(self) -> GraphedStep:  # the first kind's (GPU tests replay it by hand)
        return self._step_graphs[self.STEP_KINDS[0]]

    def _act_body(
        self, obs: torch.Tensor, noise: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        if noise is None:  # on the GPU, inside the graph
            noise = torch.randn((self.members, 1, self.act_dim), device=self.device)
        return {"action": self.explore(obs[:, None, :], noise)[:, 0].detach()}

    @torch.no_grad()
    def act(self, obs: np.ndarray, need: np.ndarray | None = None) -> np.ndarray:
        """A sampled action per member; on CPU only members in ``need`` draw noise (a guided
        member's policy does not act, and its stream is not advanced)."""
        obs_t = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32))
        if self.device.type == "cpu":
            out = self._act_body(obs_t, self.member_noise(1, need))
        else:
            out = self._act_graph(obs=obs_t)
        return out["action"].cpu().numpy()

    @torch.no_grad()
    def act_deterministic(self, obs: np.ndarray) -> np.ndarray:
        obs_t = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32)).to(self.device)
        return self.policy.deterministic(obs_t[:, None, :])[:, 0].cpu().numpy()

    @torch.no_grad()
    def act_member_deterministic(self, k: int, obs: np.ndarray) -> np.ndarray:
        """Member k's deterministic action for one observation (JSRL's curriculum test)."""
        rows = torch.zeros((self.members, 1, len(obs)), device=self.device)
        rows[k, 0] = torch.as_tensor(obs, dtype=torch.float32, device=self.device)
        return self.policy.deterministic(rows)[k, 0].cpu().numpy()

    def _sample_and_update(self, size: torch.Tensor, kind: str) -> dict[str, torch.Tensor]:
        """The GPU's whole step: replay indices, the batch, the noise and the update."""
        batch = self.buffer.sample_on_device(self.batch_size, size)
        noise = self.device_noise(batch, kind)
        return self.gradient_step(batch, noise, kind, **self.step_inputs(batch, kind))

    # bf16 autocast of the CPU update: a measurement (benchmarks/bf16_curves.py), not a
    # setting of the harness; None keeps fp32
    cpu_autocast: torch.dtype | None = None

    def update(self, rngs: list[np.random.Generator]) -> dict[str, torch.Tensor]:
        """One gradient step of every member on its own minibatch (of the kind
        ``next_step_kind`` names); per-member losses (N,)."""
        kind = self.next_step_kind()
        if kind not in self.STEP_KINDS:
            raise ContractError(f"{type(self).__name__} took a step of unknown kind '{kind}'")
        if self.device.type == "cpu":
            with no_global_draws(f"{type(self).__name__}'s gradient step"):
                batch = self.buffer.sample(self.batch_size, rngs)
                inputs = self.step_inputs(batch, kind)
                with torch.autocast(
                    "cpu",
                    dtype=self.cpu_autocast or torch.bfloat16,
                    enabled=self.cpu_autocast is not None,
                ):
                    return self.gradient_step(batch, self.cpu_noise(kind), kind, **inputs)
        self._size.fill_(self.buffer.size)
        return self._step_graphs[kind](size=self._size)

    def noise_state(self) -> dict[str, Any]:
        if self.device.type == "cpu":
            return {"generators": [g.get_state() for g in self.generators]}
        return {"cuda": torch.cuda.get_rng_state(self.device)}

    def load_noise_state(self, state: dict[str, Any]) -> None:
        if "generators" in state:
            for generator, value in zip(self.generators, state["generators"], strict=True):
                generator.set_state(value)
        else:
            torch.cuda.set_rng_state(state["cuda"], self.device)


class PolicyExplorer:
    """Chooses each member's executed action and sees each evaluation. SAC samples its
    policy; DRL-EG's, IBRL's and JSRL's explorers may hand a member's step to a guide."""

    def __init__(self, agent: OffPolicyAgent):
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


def train_members(
    bctx: BatchContext,
    agent: OffPolicyAgent,
    explorer: Callable[[OffPolicyAgent], PolicyExplorer] = PolicyExplorer,
) -> StackedReplay:
    """Train a built agent's members with ``explorer`` choosing their actions."""
    seed_device_stream(bctx)  # after the networks: building them reseeds every device
    return run_off_policy(bctx, agent, explorer(agent))


def run_off_policy(
    bctx: BatchContext, agent: OffPolicyAgent, explorer: PolicyExplorer
) -> StackedReplay:
    """The training loop of the SAC family (Algorithm 1 of the paper for DRL-EG): N envs,
    N replays, N curves, one update of every member per env step; the replay is returned.
    The executed action is what goes in the replay, guided or not."""
    cfg = agent.config
    torch.set_num_threads(cfg.torch_threads)
    env_id, total_steps = bctx.shared("env_id"), bctx.shared("total_steps")
    eval_interval, eval_episodes = bctx.shared("eval_interval"), bctx.shared("eval_episodes")
    seeds, n = bctx.seeds, len(bctx.members)
    envs = EnvBatch(env_id, seeds, bctx.env_workers)
    eval_envs = EnvBatch(env_id, [s + EVAL_SEED_OFFSET for s in seeds], bctx.env_workers)
    agent.buffer = agent.make_replay(n, envs.obs_dim, min(cfg.buffer_size, total_steps))
    buffer = agent.buffer
    batch_rngs = [np.random.default_rng(seed) for seed in seeds]
    curves: list[list[EvalPoint]] = [[] for _ in range(n)]
    alive = np.ones(n, dtype=bool)
    failures: dict[int, str] = {}
    guided_steps = np.zeros(n, dtype=np.int64)
    training = TrainingReturns(n)
    steps_since_eval = 0
    best_returns = np.full(n, -np.inf)  # for members that keep their best policy (experts)

    def fail(k: int, reason: str, steps_left: int) -> None:
        alive[k] = False
        failures[k] = reason
        bctx.on_member_failed(k, reason)
        bctx.on_steps(steps_left)  # a failed member's steps count as done for the progress

    def evaluate_and_record(step: int) -> None:
        returns = evaluate_members(eval_envs, agent.act_deterministic, eval_episodes, alive)
        train_returns = training.take()
        for k in np.flatnonzero(alive):
            gate = explorer.after_eval(k, float(np.mean(returns[k])))
            fraction = guided_steps[k] / steps_since_eval if steps_since_eval else float("nan")
            point = EvalPoint(
                step, tuple(returns[k]), float(fraction), gate, float(train_returns[k])
            )
            curves[k].append(point)
            bctx.members[k].on_eval(point)
            keep = bctx.members[k].best_policy_path
            if keep is not None and point.mean_return > best_returns[k]:
                best_returns[k] = point.mean_return
                save_checkpoint(
                    keep,
                    {
                        "policy": agent.policy.member_policy(k).state_dict(),
                        "step": step,
                        "mean_return": point.mean_return,
                    },
                )

    def save(step: int) -> None:
        save_checkpoint(
            bctx.checkpoint_path,
            {
                "step": step,
                "device": agent.device.type,
                "seeds": seeds,
                "agent": agent_state(agent),
                "explorer": explorer.state_dict(),
                "buffer": buffer.state_dict(),
                "batch_rngs": batch_rngs,
                "curves": curves,
                "alive": alive.copy(),
                "failures": dict(failures),
                "obs": obs.copy(),
                "guided_steps": guided_steps.copy(),
                "training_returns": training.state_dict(),
                "steps_since_eval": steps_since_eval,
                "envs": envs.snapshot(),
                "eval_envs": eval_envs.snapshot(),
            },
        )

    try:
        resumed = load_checkpoint(bctx.checkpoint_path)
        if resumed is None:
            start = 1
            evaluate_and_record(0)
            obs = envs.reset(seeds=seeds)
            explorer.episode_start(np.ones(n, dtype=bool))
        else:
            if resumed["device"] != agent.device.type:
                raise CheckpointDeviceError(
                    f"the batch checkpoint at {bctx.checkpoint_path} was made on "
                    f"{resumed['device']}; resume it with --device {resumed['device']}, or "
                    f"delete it to start over on {agent.device.type}"
                )
            if resumed["seeds"] != seeds:
                raise ValueError(
                    f"the checkpoint at {bctx.checkpoint_path} holds seeds "
                    f"{resumed['seeds']}, not {seeds}"
                )
            start = resumed["step"] + 1
            load_agent_state(agent, resumed["agent"])
            explorer.load_state_dict(resumed["explorer"])
            buffer.load_state_dict(resumed["buffer"])
            batch_rngs = resumed["batch_rngs"]
            alive[:] = resumed["alive"]
            for k, reason in resumed["failures"].items():  # failed before the checkpoint
                fail(k, reason, total_steps)
            guided_steps[:] = resumed["guided_steps"]
            training.load_state_dict(resumed.get("training_returns"))
            steps_since_eval = resumed["steps_since_eval"]
            obs = resumed["obs"]
            replayed = envs.restore(resumed["envs"])
            for k in np.flatnonzero(alive):
                if replayed[k] is None or not np.array_equal(replayed[k], obs[k]):
                    raise RuntimeError(
                        f"member {k}'s env did not come back to its "
                        "checkpointed state on replay (is it deterministic?)"
                    )
            eval_envs.restore(resumed["eval_envs"])
            bctx.on_resume(resumed["step"])
            for k in range(n):
                for point in resumed["curves"][k]:
                    curves[k].append(point)
                    bctx.members[k].on_eval(point)
                    best_returns[k] = max(best_returns[k], point.mean_return)
            bctx.on_steps(resumed["step"] * int(alive.sum()))
        last_checkpoint = start - 1
        idle_action = np.zeros(agent.act_dim, dtype=np.float32)

        _, _, low, high = action_space(env_id)
        for step in range(start, total_steps + 1):
            if step <= cfg.random_start_steps:  # each member draws its seed's actions
                actions = np.stack(
                    [random_start_action(seed, step, low, high) for seed in bctx.seeds]
                )
                guided = np.zeros(n, dtype=bool)
            else:
                acting = f"{type(explorer).__name__}'s choice of {type(agent).__name__}'s actions"
                with no_global_draws(acting):
                    actions, guided = explorer.choose(obs)
            # a member whose networks diverged between looks at its losses (on a GPU) fails
            # here, alone, before its NaN action reaches its env and the batch's shared
            # lookups (a KD-tree refuses a NaN state for every member)
            for k in np.flatnonzero(alive & ~np.isfinite(actions).all(axis=1)):
                fail(k, f"diverged at step {step}: a non-finite action", total_steps - step + 1)
            actions[~alive] = idle_action
            result = envs.step(actions, active=alive)
            buffer.add(obs, actions, result.rewards, result.next_obs, result.terminated)
            obs = result.obs
            ended = (result.terminated | result.truncated) & alive
            training.add(result.rewards, ended)
            if ended.any():
                explorer.episode_start(ended)
            guided_steps += guided & alive
            steps_since_eval += 1

            if step >= cfg.learning_starts:
                for _ in range(cfg.gradient_steps):
                    losses = agent.update(batch_rngs)
                if losses_due(agent.device.type, step, total_steps):
                    q_loss = losses["q_loss"].cpu().numpy()
                    for k in np.flatnonzero(alive & ~np.isfinite(q_loss)):
                        fail(
                            k,
                            f"diverged at step {step}: losses "
                            f"{ {name: float(v[k]) for name, v in losses.items()} }",
                            total_steps - step + 1,
                        )

            if step % eval_interval == 0 or step == total_steps:
                with no_global_draws("the evaluation"):
                    evaluate_and_record(step)
                guided_steps[:] = 0
                steps_since_eval = 0
            bctx.on_steps(int(alive.sum()))
            if not alive.any():
                break
            if (
                bctx.checkpoint_path is not None
                and step < total_steps
                and due(step, last_checkpoint, bctx.checkpoint_interval, bctx.deadline)
            ):
                save(step)
                last_checkpoint = step
                stop_if_past(bctx.deadline, step)
    finally:
        envs.close()
        eval_envs.close()
    return buffer
