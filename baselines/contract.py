"""The contract between the SAC family's trainer and its agents, declared once.

An agent of the family (``baselines.offpolicy.OffPolicyAgent`` and its subclasses) trains
the N members of a seed batch together, every tensor with a leading member axis. The
trainer brings acting, replay, evaluation, checkpoints and the noise streams; an algorithm
brings what :class:`AgentContract` lists as abstract:

- ``build``: its networks and optimisers (member k's drawn after ``torch.manual_seed`` of
  its seed, so a member starts the same in any batch);
- ``cpu_noise`` and ``device_noise``: every random number its gradient step needs, drawn
  from member k's generator on the CPU, from the device's generator on a GPU;
- ``gradient_step``: one step of every member on a minibatch ``[N, B, ...]`` and that noise.

What it may override, each with a default that suits plain SAC: ``explore`` (the action it
takes from its policy and a standard-normal draw), ``next_step_kind`` with ``STEP_KINDS``
(more than one kind of gradient step, such as RLPD's critic-only steps or a delayed actor
update), ``step_inputs`` (what its step needs that is computed outside it, on the CPU),
``make_replay`` and ``extra_state``. Its checkpoint holds the attributes named in
``MODULES`` (by ``state_dict``) and ``TENSORS`` (plain tensors), ``extra_state()``, and the
trainer's noise streams; ``check_contract`` refuses an agent that would leave a network out.

The reproducibility rule (docs/adding-an-algorithm.md): every random number comes from the
streams the trainer hands out. With ``BASELINES_STRICT_RANDOMNESS=1`` in the environment (the
test suite sets it) a gradient step, a choice of action or an evaluation that draws from
torch's or numpy's global generator fails with :class:`ReproducibilityError`.
"""

from __future__ import annotations

import contextlib
import copy
import os
from abc import ABC, abstractmethod
from collections.abc import Iterator
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
import torch
from torch import nn

from baselines.common.buffer import Batch
from baselines.common.stacked import StackedReplay

Noise = Any  # what cpu_noise or device_noise returns, handed unchanged to gradient_step
FULL_STEP = "full"  # the one kind of gradient step of most agents
STRICT_RANDOMNESS = "BASELINES_STRICT_RANDOMNESS"  # "1": global draws fail (tests)


class ContractError(TypeError):
    """An agent does not keep the contract (said in one line, when it is built)."""


class ReproducibilityError(RuntimeError):
    """Training drew a random number from a global generator, so a member's numbers would
    depend on its batch and on what else the process did."""


def strict_randomness() -> bool:
    """Whether draws from the global generators fail (``BASELINES_STRICT_RANDOMNESS=1``)."""
    return os.environ.get(STRICT_RANDOMNESS) == "1"


def _numpy_global_state() -> tuple:
    _, keys, position, has_gauss, gauss = np.random.get_state()
    return keys.tobytes(), position, has_gauss, gauss


@contextlib.contextmanager
def no_global_draws(what: str) -> Iterator[None]:
    """In strict mode, fail if the block advanced torch's global CPU generator or numpy's
    global one; otherwise do nothing. Only a draw changes their states, so comparing the
    states before and after finds one wherever it was made."""
    if not strict_randomness():
        yield
        return
    torch_before, numpy_before = torch.random.get_rng_state(), _numpy_global_state()
    yield
    drew = [
        name
        for name, moved in (
            ("torch's", not torch.equal(torch.random.get_rng_state(), torch_before)),
            ("numpy's", _numpy_global_state() != numpy_before),
        )
        if moved
    ]
    if drew:
        raise ReproducibilityError(
            f"{what} drew from {' and '.join(drew)} global random generator; draw from the "
            "member streams instead (cpu_noise, device_noise: docs/adding-an-algorithm.md)"
        )


@runtime_checkable
class MemberPolicies(Protocol):
    """The N members' policies as one module (``baselines.common.stacked.StackedPolicy``)."""

    action_scale: torch.Tensor  # half the action box, (act_dim,)
    action_bias: torch.Tensor  # the box's centre, (act_dim,)

    def sample(
        self,
        obs: torch.Tensor,
        generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised action per row of ``obs`` (N, B, obs_dim) and its log-density,
        from the standard-normal ``noise`` (N, B, act_dim)."""
        ...

    def deterministic(self, obs: torch.Tensor) -> torch.Tensor:
        """The action each member takes when evaluated, (N, B, act_dim)."""
        ...

    def member_policy(self, k: int) -> nn.Module:
        """Member k's policy alone, on the CPU (what ``keep_best_policy`` saves)."""
        ...


class AgentContract(ABC):
    """What a SAC-family agent writes, and what it may override (see the module docstring).

    The trainer sets ``config``, ``device``, ``seeds``, ``members``, ``act_dim``,
    ``generators`` (one CPU generator per member) and ``batch_size`` before calling
    ``build``; the agent sets ``policy`` there."""

    # what a checkpoint holds: attributes saved by state_dict (networks, optimisers) ...
    MODULES: ClassVar[tuple[str, ...]] = ()
    # ... and plain tensors (a learned temperature), copied
    TENSORS: ClassVar[tuple[str, ...]] = ()
    # the kinds of gradient step; next_step_kind picks one before each step
    STEP_KINDS: ClassVar[tuple[str, ...]] = (FULL_STEP,)

    config: Any
    device: torch.device
    seeds: list[int]
    members: int
    act_dim: int
    generators: list[torch.Generator]
    batch_size: int
    policy: MemberPolicies

    # --- what an algorithm must write ------------------------------------------------------

    @abstractmethod
    def build(self, obs_dim: int, low: np.ndarray, high: np.ndarray) -> None:
        """Make the networks and optimisers of every member, and ``policy``."""

    @abstractmethod
    def cpu_noise(self, kind: str = FULL_STEP) -> Noise:
        """The step's random numbers on the CPU, member k's from ``generators[k]`` alone."""

    @abstractmethod
    def device_noise(self, batch: Batch, kind: str = FULL_STEP) -> Noise:
        """The same numbers on a GPU, from the device's default generator (inside a CUDA
        graph, where the step is replayed)."""

    @abstractmethod
    def gradient_step(
        self, batch: Batch, noise: Noise, kind: str = FULL_STEP, **inputs: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """One step of every member; its losses, each (N,), ``q_loss`` among them (the
        trainer fails a member whose ``q_loss`` is not finite). Draws nothing itself."""

    # --- what it may override --------------------------------------------------------------

    def explore(self, obs: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """The action each member tries while training, (N, 1, act_dim), from observations
        (N, 1, obs_dim) and a standard-normal draw of the same shape as the action."""
        action, _ = self.policy.sample(obs, noise=noise)
        return action

    def next_step_kind(self) -> str:
        """The kind of the next gradient step, one of ``STEP_KINDS``; called once before
        each (it may count them: keep the count in ``extra_state``)."""
        return self.STEP_KINDS[0]

    def step_inputs(self, batch: Batch, kind: str = FULL_STEP) -> dict[str, torch.Tensor]:
        """Tensors the step needs that are computed outside it, from its minibatch (IBRL's
        imitation actions of s'); passed to ``gradient_step`` by name. An agent with any
        cannot replay its step as a CUDA graph."""
        return {}

    def make_replay(self, members: int, obs_dim: int, capacity: int) -> StackedReplay:
        """The members' replay (RLPD's keeps the demonstrations beside it)."""
        return StackedReplay(members, obs_dim, self.act_dim, capacity, self.device)

    def extra_state(self) -> dict[str, Any]:
        """Plain values a checkpoint keeps beside the modules (RLPD: its step count)."""
        return {}

    def load_extra_state(self, state: dict[str, Any]) -> None:
        pass

    # --- given by the trainer --------------------------------------------------------------

    @abstractmethod
    def noise_state(self) -> dict[str, Any]: ...

    @abstractmethod
    def load_noise_state(self, state: dict[str, Any]) -> None: ...


def _overrides(agent: AgentContract, name: str) -> bool:
    return getattr(type(agent), name) is not getattr(AgentContract, name)


def check_contract(agent: AgentContract, cuda_graphs: bool) -> None:
    """Refuse, in one line, an agent whose checkpoint would miss a network, optimiser or
    learned tensor, whose policy is not a ``MemberPolicies``, or whose step cannot be a
    CUDA graph although it is to be one."""
    name = type(agent).__name__
    for attr in (*agent.MODULES, *agent.TENSORS):
        if not hasattr(agent, attr):
            raise ContractError(f"{name} lists '{attr}' for its checkpoint but has none")
    for attr in agent.MODULES:
        if not hasattr(getattr(agent, attr), "state_dict"):
            raise ContractError(f"{name}.{attr} is in MODULES but has no state_dict")
    for attr in agent.TENSORS:
        if not isinstance(getattr(agent, attr), torch.Tensor):
            raise ContractError(f"{name}.{attr} is in TENSORS but is not a tensor")
    listed = set(agent.MODULES) | set(agent.TENSORS)
    for attr, value in vars(agent).items():
        learned = isinstance(value, nn.Module | torch.optim.Optimizer) or (
            isinstance(value, torch.Tensor) and value.requires_grad
        )
        if learned and attr not in listed:
            raise ContractError(
                f"{name}.{attr} would not be checkpointed: list it in MODULES (or TENSORS)"
            )
    if not isinstance(getattr(agent, "policy", None), MemberPolicies):
        raise ContractError(f"{name}.policy must be a MemberPolicies (a StackedPolicy)")
    if not agent.STEP_KINDS or len(set(agent.STEP_KINDS)) != len(agent.STEP_KINDS):
        raise ContractError(f"{name}.STEP_KINDS must name its kinds of gradient step once each")
    if cuda_graphs and agent.device.type == "cuda" and _overrides(agent, "step_inputs"):
        raise ContractError(
            f"{name} computes step inputs outside its gradient step: build it with "
            "cuda_graphs=False"
        )


def agent_state(agent: AgentContract) -> dict[str, Any]:
    """What a checkpoint keeps of an agent: its MODULES' state dicts, its TENSORS, its noise
    streams and its extra state, under those names."""
    state = {name: copy.deepcopy(getattr(agent, name).state_dict()) for name in agent.MODULES}
    for name in agent.TENSORS:
        state[name] = getattr(agent, name).detach().cpu().clone()
    state["noise"] = agent.noise_state()
    state["extra"] = agent.extra_state()
    return state


def load_agent_state(agent: AgentContract, state: dict[str, Any]) -> None:
    """Put a checkpoint's ``agent_state`` back into an agent built as it was."""
    for name in agent.MODULES:
        try:
            getattr(agent, name).load_state_dict(state[name])
        except ValueError as exc:
            if "parameter groups" not in str(exc):
                raise
            raise ValueError(
                f"this batch checkpoint's {name} predates the CPU batches' two Adam groups "
                "(docs/reproducibility.md), so it cannot resume; delete the batch's "
                "checkpoint directory (.batch-* in the run store) to start it over"
            ) from None
    with torch.no_grad():
        for name in agent.TENSORS:
            getattr(agent, name).copy_(state[name])
    agent.load_noise_state(state["noise"])
    agent.load_extra_state(state.get("extra", {}))
