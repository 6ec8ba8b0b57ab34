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
(``baselines.training_loop``) steps the N envs together; a member whose action or losses
turn NaN or inf fails alone. Checkpoints hold the whole batch, mid-episode too (the envs
replay their actions).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from baselines.common.context import BatchContext
from baselines.common.device import GraphedStep
from baselines.common.stacked import StackedMLP, StackedPolicy, StackedReplay
from baselines.contract import (
    AgentContract,
    ContractError,
    check_contract,
    no_global_draws,
)
from baselines.training_loop import (  # noqa: F401  (re-exported: the trainer's interface)
    DIVERGENCE_CHECK_INTERVAL,
    PolicyExplorer,
    action_space,
    evaluate_members,
    losses_due,
    run_off_policy,
)


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


def train_members(
    bctx: BatchContext,
    agent: OffPolicyAgent,
    explorer: Callable[[OffPolicyAgent], PolicyExplorer] = PolicyExplorer,
) -> StackedReplay:
    """Train a built agent's members with ``explorer`` choosing their actions."""
    seed_device_stream(bctx)  # after the networks: building them reseeds every device
    return run_off_policy(bctx, agent, explorer(agent))
