"""Seed-batched training: N runs of SAC, twin-Q SAC, DRL-EG, RLPD or IBRL in one process.

The members of a batch share algorithm, env, budget and network shapes and differ in seed
(DRL-EG members may also differ in T2 and sigma, which change no shape). Each member is a
run of its own: it starts from the weights the one-run path gives its seed (the one-run
agent is built, then its weights are stacked), and on CPU it draws its exploration noise,
replay indices and guider noise from the very streams the one-run path uses. Every network
is a stack of N (``baselines.common.stacked``): one batched product per layer serves all
members, and no statistic is shared across them. Member k's numbers therefore do not depend
on which other members share its batch.

On a GPU the gradient step of all N members (replay sampling included) is one CUDA graph
replay, and so is the policy's action for all N (not IBRL's: its imitation actions come from
the CPU); there the members draw their noise and replay indices from one device generator
for the batch (GPU curves are not bit-reproducible in any case).

The loop is ``baselines.sac.run_off_policy`` for N envs stepped together
(``envs.vector.EnvBatch``). A member whose losses turn NaN or inf fails alone: its env stops,
its failure is reported, and the others go on. Checkpoints hold the whole batch and may be
taken in the middle of episodes: the envs are restored by replaying their episode's actions.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.checkpoint import (
    CheckpointDeviceError,
    due,
    load_checkpoint,
    save_checkpoint,
    stop_if_past,
)
from baselines.common.context import EvalPoint, TrainContext
from baselines.common.device import GraphedStep
from baselines.common.evaluation import EVAL_SEED_OFFSET, TrainingReturns
from baselines.common.random_start import random_start_action
from baselines.common.stacked import (
    StackedMLP,
    StackedNormMLP,
    StackedPolicy,
    StackedReplay,
    StackedSymmetricReplay,
    critic_ensembles,
    critic_pairs,
    member_adam,
    pair_critics,
)
from baselines.drl_eg import (
    DRLEGConfig,
    DRLEGTwinQConfig,
    Guidance,
    fit_gmm,
    fit_neural_guider,
    functional_discriminator,
    functional_guider,
    gmm_discriminator,
)
from baselines.ibrl import IBRLConfig, ImitationPolicy, preloaded_buffer
from baselines.registry import register_batched
from baselines.rlpd import RLPDAgent, RLPDConfig, demo_transitions_or_fail
from baselines.sac import SACAgent, SACConfig, frozen, q_target, v_target
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from envs import make_env
from envs.vector import EnvBatch


@dataclass
class BatchContext:
    """What the runner hands a batched trainer: one ``TrainContext`` per member (task,
    seed, budget, demonstrations, curve sink) and what the batch shares."""

    members: list[TrainContext]
    device: str = "cpu"
    cuda_graphs: bool = True
    env_workers: int = 0  # processes stepping the envs; 0: in this process
    on_steps: Callable[[int], None] = field(default=lambda n: None)  # env steps, all members
    on_resume: Callable[[int], None] = field(default=lambda step: None)
    on_member_failed: Callable[[int, str], None] = field(default=lambda k, reason: None)
    checkpoint_path: Path | None = None
    checkpoint_interval: int = 0
    deadline: float | None = None  # as TrainContext.deadline, for the batch as a whole

    @property
    def seeds(self) -> list[int]:
        return [m.seed for m in self.members]

    def shared(self, name: str) -> Any:
        """A setting every member must have alike."""
        values = {getattr(m, name) for m in self.members}
        if len(values) != 1:
            raise ValueError(f"the members of a batch differ in {name}: {sorted(values)}")
        return values.pop()


def _space(env_id: str) -> tuple[int, int, np.ndarray, np.ndarray]:
    probe = make_env(env_id)
    obs_dim, space = probe.observation_space.shape[0], probe.action_space
    probe.close()
    return obs_dim, space.shape[0], space.low, space.high


class StackedActor:
    """Acting and noise for N members. On CPU member k's noise comes from its one-run
    generator (seed + 1), drawn in the one-run order; on a GPU from the batch's generator."""

    policy: StackedPolicy
    device: torch.device
    members: int
    act_dim: int
    generators: list[torch.Generator]

    def _member_noise(self, rows: int, need: np.ndarray | None = None) -> torch.Tensor:
        noise = torch.zeros((self.members, rows, self.act_dim))
        for k, generator in enumerate(self.generators):
            if need is None or need[k]:
                noise[k] = torch.randn((rows, self.act_dim), generator=generator)
        return noise

    def _setup_acting(self, cuda_graphs: bool) -> None:
        self._act_graph = GraphedStep(self._act_body, self.device, cuda_graphs)

    def _act_body(
        self, obs: torch.Tensor, noise: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        if noise is None:  # on the GPU, inside the graph
            noise = torch.randn((self.members, 1, self.act_dim), device=self.device)
        action, _ = self.policy.sample(obs[:, None, :], noise=noise)
        return {"action": action[:, 0].detach()}

    @torch.no_grad()
    def act(self, obs: np.ndarray, need: np.ndarray | None = None) -> np.ndarray:
        """A sampled action per member; on CPU only members in ``need`` draw noise (a guided
        member's policy does not act, and its one-run stream is not advanced)."""
        obs_t = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32))
        if self.device.type == "cpu":
            out = self._act_body(obs_t, self._member_noise(1, need))
        else:
            out = self._act_graph(obs=obs_t)
        return out["action"].cpu().numpy()

    @torch.no_grad()
    def act_deterministic(self, obs: np.ndarray) -> np.ndarray:
        obs_t = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32)).to(self.device)
        return self.policy.deterministic(obs_t[:, None, :])[:, 0].cpu().numpy()

    def make_replay(self, members: int, obs_dim: int, capacity: int) -> StackedReplay:
        """The batch's replay (RLPD's adds the demonstrations beside it)."""
        return StackedReplay(members, obs_dim, self.act_dim, capacity, self.device)

    def extra_state(self) -> dict[str, Any]:
        """What a checkpoint keeps beside the modules and the noise (RLPD: its step count)."""
        return {}

    def load_extra_state(self, state: dict[str, Any]) -> None:
        pass

    def _setup_updates(self, batch_size: int, cuda_graphs: bool) -> None:
        self.batch_size = batch_size
        self.buffer: StackedReplay | None = None
        self._update_graph = GraphedStep(self._sample_and_update, self.device, cuda_graphs)
        self._size = torch.zeros((), dtype=torch.long, device=self.device)

    def _sample_and_update(self, size: torch.Tensor) -> dict[str, torch.Tensor]:
        """The GPU's whole step: replay indices, the batch, the noise and the update."""
        uniform = torch.rand((self.members, self.batch_size), device=self.device)
        indices = torch.minimum((uniform * size).long(), size - 1)
        batch = self.buffer.gather(indices)
        return self._gradient_step(batch, self._device_noise(batch))

    # bf16 autocast of the CPU update: a measurement (benchmarks/bf16_curves.py), not a
    # setting of the harness; None keeps fp32
    cpu_autocast: torch.dtype | None = None

    def update(self, rngs: list[np.random.Generator]) -> dict[str, torch.Tensor]:
        """One gradient step of every member on its own minibatch; per-member losses (N,)."""
        if self.device.type == "cpu":
            batch = self.buffer.sample(self.batch_size, rngs)
            with torch.autocast(
                "cpu",
                dtype=self.cpu_autocast or torch.bfloat16,
                enabled=self.cpu_autocast is not None,
            ):
                return self._gradient_step(batch, self._cpu_noise())
        self._size.fill_(self.buffer.size)
        return self._update_graph(size=self._size)

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

    def _cpu_noise(self) -> Any:
        raise NotImplementedError

    def _device_noise(self, batch: Batch) -> Any:
        raise NotImplementedError

    def _gradient_step(self, batch: Batch, noise: Any) -> dict[str, torch.Tensor]:
        raise NotImplementedError


class StackedSACAgent(StackedActor):
    """The paper's V-network SAC (``baselines.sac.SACAgent``) for N members."""

    def __init__(
        self, agents: list[SACAgent], config: SACConfig, device: str, cuda_graphs: bool = True
    ):
        self.config, self.device = config, torch.device(device)
        self.members, self.act_dim = len(agents), agents[0].policy.action_scale.shape[0]
        self.critics = pair_critics([a.q1.net for a in agents], [a.q2.net for a in agents]).to(
            self.device
        )
        self.v = StackedMLP.stack([a.v.net for a in agents]).to(self.device)
        self.v_target = StackedMLP.stack([a.v_target.net for a in agents]).to(self.device)
        first = agents[0].policy
        self.policy = StackedPolicy(
            StackedMLP.stack([a.policy.trunk for a in agents]),
            first.action_scale,
            first.action_bias,
        ).to(self.device)
        lr = config.learning_rate
        self.q_optimizer = member_adam(self.critics.parameters(), lr, self.device)
        self.v_optimizer = member_adam(self.v.parameters(), lr, self.device)
        self.policy_optimizer = member_adam(self.policy.parameters(), lr, self.device)
        self.generators = [a.noise for a in agents]
        self._setup_acting(cuda_graphs)
        self._setup_updates(config.batch_size, cuda_graphs)

    MODULES = (
        "critics",
        "v",
        "v_target",
        "policy",
        "q_optimizer",
        "v_optimizer",
        "policy_optimizer",
    )

    def _cpu_noise(self) -> torch.Tensor:
        return self._member_noise(self.batch_size).to(self.device)

    def _device_noise(self, batch: Batch) -> torch.Tensor:
        return torch.randn(batch.actions.shape, device=self.device)

    def _gradient_step(self, batch: Batch, noise: torch.Tensor) -> dict[str, torch.Tensor]:
        cfg = self.config
        obs, actions = batch.observations, batch.actions
        with torch.no_grad():
            y_q = q_target(
                batch.rewards,
                batch.terminated,
                self.v_target(batch.next_observations).squeeze(-1),
                cfg.gamma,
                cfg.reward_scale,
            )
        q = critic_pairs(self.critics, obs, actions)  # (N, 2, B)
        q_losses = 0.5 * (q - y_q[:, None]).pow(2).mean(-1).sum(-1)  # per member
        self.q_optimizer.zero_grad()
        q_losses.sum().backward()
        self.q_optimizer.step()

        new_actions, log_prob = self.policy.sample(obs, noise=noise)
        with frozen(self.critics):
            q_new = critic_pairs(self.critics, obs, new_actions).min(dim=1).values
        v_losses = 0.5 * (self.v(obs).squeeze(-1) - v_target(q_new, log_prob).detach()).pow(2).mean(
            -1
        )
        policy_losses = (log_prob - q_new).mean(-1)
        self.v_optimizer.zero_grad()
        v_losses.sum().backward()
        self.v_optimizer.step()
        self.policy_optimizer.zero_grad()
        policy_losses.sum().backward()
        self.policy_optimizer.step()

        with torch.no_grad():
            torch._foreach_lerp_(
                list(self.v_target.parameters()), list(self.v.parameters()), cfg.tau
            )
        return {
            "q_loss": q_losses.detach(),
            "v_loss": v_losses.detach(),
            "policy_loss": policy_losses.detach(),
            "entropy": -log_prob.detach().mean(-1),
        }


class StackedTwinQAgent(StackedActor):
    """Twin-Q, learned-temperature SAC (``baselines.sac_twin_q``) for N members."""

    def __init__(
        self,
        agents: list[TwinQSACAgent],
        config: TwinQSACConfig,
        device: str,
        cuda_graphs: bool = True,
    ):
        self.config, self.device = config, torch.device(device)
        self.members, self.act_dim = len(agents), agents[0].policy.action_scale.shape[0]
        self.critics = self._stack_ensembles([a.critics for a in agents]).to(self.device)
        self.critics_target = self._stack_ensembles([a.critics_target for a in agents]).to(
            self.device
        )
        first = agents[0].policy
        self.policy = StackedPolicy(
            StackedMLP.stack([a.policy.trunk for a in agents]),
            first.action_scale,
            first.action_bias,
        ).to(self.device)
        self.log_alpha = torch.cat([a.log_alpha.detach() for a in agents]).to(self.device)
        self.log_alpha.requires_grad_(True)
        self.target_entropy = agents[0].target_entropy
        lr = config.learning_rate
        self.critic_optimizer = member_adam(self.critics.parameters(), lr, self.device)
        self.policy_optimizer = member_adam(self.policy.parameters(), lr, self.device)
        self.alpha_optimizer = member_adam([self.log_alpha], lr, self.device)
        self.generators = [a.noise for a in agents]
        self._setup_acting(cuda_graphs)
        self._setup_updates(config.batch_size, cuda_graphs)

    MODULES = (
        "critics",
        "critics_target",
        "policy",
        "critic_optimizer",
        "policy_optimizer",
        "alpha_optimizer",
    )

    @staticmethod
    def _stack_ensembles(ensembles: list) -> StackedMLP:
        """Each member's (2, in, out) critic pair, member-major, as one stack of 2N."""
        return StackedMLP(
            [
                torch.cat([e.weights[i].detach() for e in ensembles])
                for i in range(len(ensembles[0].weights))
            ],
            [
                torch.cat([e.biases[i].detach() for e in ensembles])
                for i in range(len(ensembles[0].biases))
            ],
        )

    def _cpu_noise(self) -> tuple[torch.Tensor, torch.Tensor]:
        # member k draws next_noise, then new_noise, from its own stream, as one run does
        next_noise = torch.zeros((self.members, self.batch_size, self.act_dim))
        new_noise = torch.zeros_like(next_noise)
        for k, generator in enumerate(self.generators):
            next_noise[k] = torch.randn((self.batch_size, self.act_dim), generator=generator)
            new_noise[k] = torch.randn((self.batch_size, self.act_dim), generator=generator)
        return next_noise.to(self.device), new_noise.to(self.device)

    def _device_noise(self, batch: Batch) -> tuple[torch.Tensor, torch.Tensor]:
        return (
            torch.randn(batch.actions.shape, device=self.device),
            torch.randn(batch.actions.shape, device=self.device),
        )

    def next_state_value(
        self,
        next_obs: torch.Tensor,
        next_noise: torch.Tensor,
        alpha: torch.Tensor,
        **target_inputs: torch.Tensor,
    ) -> torch.Tensor:
        """Each member's soft value of s' (N, B) under its target critics (IBRL overrides)."""
        next_actions, next_log_prob = self.policy.sample(next_obs, noise=next_noise)
        next_q = critic_pairs(self.critics_target, next_obs, next_actions).min(dim=1).values
        return next_q - alpha * next_log_prob

    def _gradient_step(
        self, batch: Batch, noise: tuple[torch.Tensor, torch.Tensor], **target_inputs: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        cfg = self.config
        next_noise, new_noise = noise
        obs, actions = batch.observations, batch.actions
        alpha = self.log_alpha.detach().exp()[:, None]  # (N, 1)

        with torch.no_grad():
            next_value = self.next_state_value(
                batch.next_observations, next_noise, alpha, **target_inputs
            )
            y = batch.rewards + cfg.gamma * (1.0 - batch.terminated) * next_value
        q_losses = 0.5 * (critic_pairs(self.critics, obs, actions) - y[:, None]).pow(2).mean(
            -1
        ).sum(-1)
        self.critic_optimizer.zero_grad()
        q_losses.sum().backward()
        self.critic_optimizer.step()

        new_actions, log_prob = self.policy.sample(obs, noise=new_noise)
        with frozen(self.critics):
            q_new = critic_pairs(self.critics, obs, new_actions).min(dim=1).values
        policy_losses = (alpha * log_prob - q_new).mean(-1)
        self.policy_optimizer.zero_grad()
        policy_losses.sum().backward()
        self.policy_optimizer.step()

        alpha_losses = -(self.log_alpha[:, None] * (log_prob.detach() + self.target_entropy)).mean(
            -1
        )
        self.alpha_optimizer.zero_grad()
        alpha_losses.sum().backward()
        self.alpha_optimizer.step()

        with torch.no_grad():
            torch._foreach_lerp_(
                list(self.critics_target.parameters()), list(self.critics.parameters()), cfg.tau
            )
        return {
            "q_loss": q_losses.detach(),
            "policy_loss": policy_losses.detach(),
            "alpha": alpha[:, 0],
            "entropy": -log_prob.detach().mean(-1),
        }


class StackedRLPDAgent(StackedTwinQAgent):
    """RLPD (``baselines.rlpd``) for N members: twin-Q SAC's stacked policy and temperature,
    each member's ensemble of LayerNorm critics (its target a minimum over its own random
    subset of them), minibatches half demonstrations, and ``utd`` critic steps per actor
    step. On CPU member k draws its noise, subsets and replay rows in its one-run order."""

    def __init__(
        self,
        agents: list[RLPDAgent],
        config: RLPDConfig,
        demos: ReplayBuffer,
        device: str,
        cuda_graphs: bool = True,
    ):
        self.per_member = config.num_qs
        self.demos = demos  # the demonstration transitions, as the one-run path loads them
        super().__init__(agents, config, device, cuda_graphs)
        self.critic_updates = 0
        self._critic_graph = GraphedStep(self._sample_and_critic_step, self.device, cuda_graphs)

    @staticmethod
    def _stack_ensembles(ensembles: list) -> StackedMLP:
        stacked = StackedTwinQAgent._stack_ensembles(ensembles)
        if not hasattr(ensembles[0], "norm_gains"):
            return stacked
        return StackedNormMLP(
            list(stacked.weights),
            list(stacked.biases),
            [
                torch.cat([e.norm_gains[i].detach() for e in ensembles])
                for i in range(len(ensembles[0].norm_gains))
            ],
            [
                torch.cat([e.norm_biases[i].detach() for e in ensembles])
                for i in range(len(ensembles[0].norm_biases))
            ],
        )

    def make_replay(self, members: int, obs_dim: int, capacity: int) -> StackedReplay:
        return StackedSymmetricReplay(
            self.demos, members, obs_dim, self.act_dim, capacity, self.device
        )

    def extra_state(self) -> dict[str, Any]:
        return {"critic_updates": self.critic_updates}

    def load_extra_state(self, state: dict[str, Any]) -> None:
        self.critic_updates = state["critic_updates"]

    def update(self, rngs: list[np.random.Generator]) -> dict[str, torch.Tensor]:
        """One critic step of every member on its own symmetric minibatch; after every
        ``utd``-th, the actor and temperature steps too. Per-member losses (N,)."""
        self.critic_updates += 1
        actor = self.critic_updates % self.config.utd == 0
        if self.device.type == "cpu":
            batch = self.buffer.sample(self.batch_size, rngs)
            return self._rlpd_step(batch, self._cpu_noise(actor), actor)
        self._size.fill_(self.buffer.size)
        return (self._update_graph if actor else self._critic_graph)(size=self._size)

    def _cpu_noise(self, actor: bool = True) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        # member k draws next_noise, its subset, then new_noise, as its one run's update does
        cfg = self.config
        next_noise = torch.zeros((self.members, self.batch_size, self.act_dim))
        new_noise = torch.zeros_like(next_noise)
        subsets = torch.zeros((self.members, cfg.num_min_qs), dtype=torch.long)
        for k, generator in enumerate(self.generators):
            next_noise[k] = torch.randn((self.batch_size, self.act_dim), generator=generator)
            subsets[k] = torch.randperm(cfg.num_qs, generator=generator)[: cfg.num_min_qs]
            if actor:
                new_noise[k] = torch.randn((self.batch_size, self.act_dim), generator=generator)
        return next_noise, subsets, new_noise

    def _device_noise(self, batch: Batch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        cfg = self.config
        subsets = torch.rand((self.members, cfg.num_qs), device=self.device).argsort(dim=-1)[
            :, : cfg.num_min_qs
        ]
        return (
            torch.randn(batch.actions.shape, device=self.device),
            subsets,
            torch.randn(batch.actions.shape, device=self.device),
        )

    def _symmetric_batch(self, size: torch.Tensor) -> Batch:
        half = self.batch_size // 2
        n_demos = len(self.buffer.demos)
        # a bound from a Python number: a tensor made here would copy to the device, which
        # graph capture forbids
        demo = (
            (torch.rand((self.members, half), device=self.device) * n_demos)
            .long()
            .clamp_(max=n_demos - 1)
        )
        uniform = torch.rand((self.members, self.batch_size - half), device=self.device)
        online = torch.minimum((uniform * size).long(), size - 1)
        return self.buffer.gather_halves(demo, online)

    def _sample_and_update(self, size: torch.Tensor) -> dict[str, torch.Tensor]:
        batch = self._symmetric_batch(size)
        return self._rlpd_step(batch, self._device_noise(batch), actor=True)

    def _sample_and_critic_step(self, size: torch.Tensor) -> dict[str, torch.Tensor]:
        batch = self._symmetric_batch(size)
        return self._rlpd_step(batch, self._device_noise(batch), actor=False)

    def _rlpd_step(
        self, batch: Batch, noise: tuple[torch.Tensor, torch.Tensor, torch.Tensor], actor: bool
    ) -> dict[str, torch.Tensor]:
        cfg = self.config
        next_noise, subsets, new_noise = (t.to(self.device) for t in noise)
        obs, actions, rows = batch.observations, batch.actions, batch.actions.shape[1]
        alpha = self.log_alpha.detach().exp()[:, None]  # (N, 1)

        with torch.no_grad():
            next_actions, next_log_prob = self.policy.sample(
                batch.next_observations, noise=next_noise
            )
            next_q = critic_ensembles(
                self.critics_target, batch.next_observations, next_actions, self.per_member
            )  # (N, Q, B)
            chosen = next_q.gather(1, subsets[:, :, None].expand(-1, -1, rows))
            next_value = chosen.min(dim=1).values
            if cfg.backup_entropy:
                next_value = next_value - alpha * next_log_prob
            y = batch.rewards + cfg.gamma * (1.0 - batch.terminated) * next_value
        q = critic_ensembles(self.critics, obs, actions, self.per_member)
        q_losses = (q - y[:, None]).pow(2).mean(dim=(1, 2))  # per member, as one run's mean
        self.critic_optimizer.zero_grad()
        q_losses.sum().backward()
        self.critic_optimizer.step()
        with torch.no_grad():
            torch._foreach_lerp_(
                list(self.critics_target.parameters()), list(self.critics.parameters()), cfg.tau
            )
        losses = {"q_loss": q_losses.detach()}
        if not actor:
            return losses

        new_actions, log_prob = self.policy.sample(obs, noise=new_noise)
        with frozen(self.critics):
            q_new = critic_ensembles(self.critics, obs, new_actions, self.per_member).mean(dim=1)
        policy_losses = (alpha * log_prob - q_new).mean(-1)
        self.policy_optimizer.zero_grad()
        policy_losses.sum().backward()
        self.policy_optimizer.step()

        # RLPD's temperature loss on alpha itself, each member on its own entropy
        entropy = -log_prob.detach().mean(-1)  # (N,)
        alpha_losses = self.log_alpha.exp() * (entropy - self.target_entropy)
        self.alpha_optimizer.zero_grad()
        alpha_losses.sum().backward()
        self.alpha_optimizer.step()
        return {
            **losses,
            "policy_loss": policy_losses.detach(),
            "alpha": alpha[:, 0],
            "entropy": entropy,
        }


class StackedIBRLAgent(StackedTwinQAgent):
    """IBRL (``baselines.ibrl``) for N members: twin-Q SAC's stacked networks; each member
    acts and bootstraps with the higher-valued (by its target critics) of its actor's
    proposal and its imitation policy's, and its replay starts with the demonstration
    transitions. The imitation actions come from the CPU (a KD-tree query or a BC net), so
    no step is a CUDA graph; on CPU member k draws its noise and rows in its one-run order."""

    def __init__(
        self,
        agents: list[TwinQSACAgent],
        config: IBRLConfig,
        imitations: list[ImitationPolicy],
        demos: Any,
        device: str,
    ):
        super().__init__(agents, config, device, cuda_graphs=False)
        self.imitations = imitations
        self.demos = demos  # a DemoSet with transitions to preload, or None

    def imitation_actions(self, states: np.ndarray) -> np.ndarray:
        """mu_k(s) of member k's states (N, B, obs_dim): (N, B, act_dim) float32."""
        if self.config.imitation == "functional":  # one tree answers every member
            flat = self.imitations[0](states.reshape(-1, states.shape[-1]))
            return flat.reshape(*states.shape[:2], -1).astype(np.float32)
        return np.stack([mu(rows) for mu, rows in zip(self.imitations, states)])

    @torch.no_grad()
    def propose(self, obs: np.ndarray, deterministic: bool) -> tuple[np.ndarray, np.ndarray]:
        """Each member's executed action and whether its imitation policy proposed it; the
        actor's proposal is sampled unless ``deterministic``, and ties go to the actor."""
        obs_t = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32)).to(self.device)[
            :, None, :
        ]
        if deterministic:
            rl_action = self.policy.deterministic(obs_t)
        else:
            noise = (
                self._member_noise(1)
                if self.device.type == "cpu"
                else torch.randn((self.members, 1, self.act_dim), device=self.device)
            )
            rl_action, _ = self.policy.sample(obs_t, noise=noise.to(self.device))
        il_action = torch.from_numpy(self.imitation_actions(obs[:, None, :])).to(self.device)
        pair = torch.cat([rl_action, il_action], dim=1)  # (N, 2, act_dim)
        q = (
            critic_pairs(self.critics_target, obs_t.expand(-1, 2, -1), pair).min(dim=1).values
        )  # (N, 2): min over each member's two critics
        imitated = q[:, 1] > q[:, 0]
        action = torch.where(imitated[:, None], pair[:, 1], pair[:, 0])
        return action.cpu().numpy(), imitated.cpu().numpy()

    def act(self, obs: np.ndarray, need: np.ndarray | None = None) -> np.ndarray:
        return self.propose(obs, deterministic=False)[0]

    def act_deterministic(self, obs: np.ndarray) -> np.ndarray:
        if not self.config.eval_with_imitation:
            return super().act_deterministic(obs)
        return self.propose(obs, deterministic=True)[0]

    def make_replay(self, members: int, obs_dim: int, capacity: int) -> StackedReplay:
        """Each member's replay, the demonstration transitions first (``preloaded_buffer``)."""
        if self.demos is None:
            return super().make_replay(members, obs_dim, capacity)
        n = len(self.demos.observations)
        replay = StackedReplay(members, obs_dim, self.act_dim, n + capacity, self.device)

        def tile(x: Any) -> np.ndarray:  # one transition, the same for every member
            return np.repeat(np.asarray(x, dtype=np.float32)[None], members, axis=0)

        for i in range(n):
            replay.add(
                tile(self.demos.observations[i]),
                tile(self.demos.actions[i]),
                tile(self.demos.rewards[i]),
                tile(self.demos.next_observations[i]),
                tile(float(bool(self.demos.terminated[i]))),
            )
        return replay

    def update(self, rngs: list[np.random.Generator]) -> dict[str, torch.Tensor]:
        if self.device.type == "cpu":
            batch = self.buffer.sample(self.batch_size, rngs)
            noise = self._cpu_noise()
        else:
            uniform = torch.rand((self.members, self.batch_size), device=self.device)
            size = self.buffer.size
            batch = self.buffer.gather((uniform * size).long().clamp_(max=size - 1))
            noise = self._device_noise(batch)
        # mu(s') off the gradient step, as the one-run IBRL computes it
        next_il = self.imitation_actions(batch.next_observations.cpu().numpy())
        return self._gradient_step(
            batch, noise, next_il_actions=torch.from_numpy(next_il).to(self.device)
        )

    def next_state_value(
        self,
        next_obs: torch.Tensor,
        next_noise: torch.Tensor,
        alpha: torch.Tensor,
        next_il_actions: torch.Tensor,
    ) -> torch.Tensor:
        """max(Q'(s', a'), Q'(s', mu(s'))) - alpha log pi(a'|s') per member, a' ~ pi(.|s')."""
        next_actions, next_log_prob = self.policy.sample(next_obs, noise=next_noise)
        q_rl = critic_pairs(self.critics_target, next_obs, next_actions).min(dim=1).values
        q_il = critic_pairs(self.critics_target, next_obs, next_il_actions).min(dim=1).values
        return torch.maximum(q_rl, q_il) - alpha * next_log_prob


def agent_state(agent: StackedActor) -> dict[str, Any]:
    state = {name: copy.deepcopy(getattr(agent, name).state_dict()) for name in agent.MODULES}
    if isinstance(agent, StackedTwinQAgent):
        state["log_alpha"] = agent.log_alpha.detach().cpu().clone()
    state["noise"] = agent.noise_state()
    state["extra"] = agent.extra_state()
    return state


def load_agent_state(agent: StackedActor, state: dict[str, Any]) -> None:
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
    if "log_alpha" in state:
        with torch.no_grad():
            agent.log_alpha.copy_(state["log_alpha"])
    agent.load_noise_state(state["noise"])
    agent.load_extra_state(state.get("extra", {}))


class StackedExplorer:
    """SAC's choice for N members: each samples its policy."""

    def __init__(self, agent: StackedActor):
        self.agent = agent

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.agent.act(obs), np.zeros(len(obs), dtype=bool)

    def after_eval(self, k: int, mean_return: float) -> bool | None:
        return None

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        pass


class StackedGuidedExplorer(StackedExplorer):
    """Algorithm 1's choice for N members: member k takes its guider's action while its
    R_demo > R_pi and D(s_k) = 1. One KD-tree of the shared demonstrations answers all N
    states in one query; each member keeps its own T2, sigma, guider stream and gate."""

    def __init__(
        self,
        agent: StackedActor,
        configs: list,
        demos: Any,
        low: np.ndarray,
        high: np.ndarray,
        seeds: list[int],
    ):
        super().__init__(agent)
        self.configs, self.low, self.high = configs, low, high
        # one Guidance fits the tree (and the GMM or MLP of member 0); the others share the
        # tree and fit their own models from their own seeds, as their one-run guiders do
        first = Guidance(configs[0], demos, low, high, seeds[0])
        self.tree, self.demo_actions = first.tree, first.actions
        self.rngs = [np.random.default_rng([seed, 2]) for seed in seeds]
        self.gmms: list[Any] = []
        self.nets: list[Any] = []
        for k, (config, seed) in enumerate(zip(configs, seeds)):
            if config.discriminator == "gmm":
                self.gmms.append(
                    (first.gmm, first.log_threshold)
                    if k == 0
                    else fit_gmm(
                        first.states, config.gmm_components, config.gmm_threshold_quantile, seed
                    )
                )
            if config.guider == "neural":
                self.nets.append(
                    first.net
                    if k == 0
                    else fit_neural_guider(
                        demos, config.neural_guider_hidden, config.neural_guider_steps, seed
                    )
                )
        self.thresholds = np.array([c.guide_threshold for c in configs])
        self.demo_return = demos.mean_return
        self.policy_returns = np.zeros(len(configs))  # Algorithm 1: R_pi <- 0 before testing

    def decide(self, obs: np.ndarray, gate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(s) for the members in ``gate``, and each nearest demonstration's index (-1
        where not searched): the same as each member's one-run ``Guidance`` decides."""
        n = len(obs)
        guided = np.zeros(n, dtype=bool)
        index = np.full(n, -1)
        functional = np.array([c.discriminator == "functional" for c in self.configs]) & gate
        if functional.any():
            bound = self.thresholds[functional].max() * (1 + 1e-9) + 1e-150
            distance, found = self.tree.query(
                obs[functional].astype(np.float64), distance_upper_bound=bound
            )
            rows = np.flatnonzero(functional)
            for row, d, i in zip(rows, distance, found):
                guided[row] = functional_discriminator(float(d), self.thresholds[row])
                index[row] = i if guided[row] else -1
        for k in np.flatnonzero(gate & ~functional):
            gmm, log_threshold = self.gmms[k]
            guided[k] = gmm_discriminator(gmm, obs[k].astype(np.float64), log_threshold)
        return guided, index

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        gate = self.demo_return > self.policy_returns
        guided, index = self.decide(obs, gate)
        actions = self.agent.act(obs, need=~guided)
        for k in np.flatnonzero(guided):
            config = self.configs[k]
            if config.guider == "functional":
                i = index[k] if index[k] >= 0 else self.tree.query(obs[k].astype(np.float64))[1]
                actions[k] = functional_guider(
                    self.demo_actions, i, config.guide_noise_std, self.rngs[k], self.low, self.high
                )
            else:
                with torch.no_grad():
                    mean = self.nets[k](torch.as_tensor(obs[k], dtype=torch.float32)[None]).numpy()[
                        0
                    ]
                noisy = mean + config.guide_noise_std * self.rngs[k].standard_normal(mean.shape)
                actions[k] = np.clip(noisy, self.low, self.high).astype(np.float32)
        return actions, guided

    def after_eval(self, k: int, mean_return: float) -> bool:
        self.policy_returns[k] = mean_return
        return bool(self.demo_return > mean_return)

    def state_dict(self) -> dict[str, Any]:
        return {"policy_returns": self.policy_returns.copy(), "guider_rngs": self.rngs}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.policy_returns = state["policy_returns"].copy()
        self.rngs = state["guider_rngs"]


class StackedIBRLExplorer(StackedExplorer):
    """IBRL's choice for N members; a step counts as guided where the imitation action won."""

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.agent.propose(obs, deterministic=False)


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


def run_stacked_off_policy(
    bctx: BatchContext, agent: StackedActor, explorer: StackedExplorer
) -> None:
    """``run_off_policy`` for a batch: N envs, N buffers, N curves, one update per step."""
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

        _, _, low, high = _space(env_id)
        for step in range(start, total_steps + 1):
            if step <= cfg.random_start_steps:  # each member draws its one-run actions
                actions = np.stack(
                    [random_start_action(seed, step, low, high) for seed in bctx.seeds]
                )
                guided = np.zeros(n, dtype=bool)
            else:
                actions, guided = explorer.choose(obs)
            actions[~alive] = idle_action
            result = envs.step(actions, active=alive)
            buffer.add(obs, actions, result.rewards, result.next_obs, result.terminated)
            obs = result.obs
            training.add(result.rewards, (result.terminated | result.truncated) & alive)
            guided_steps += guided & alive
            steps_since_eval += 1

            if step >= cfg.learning_starts:
                for _ in range(cfg.gradient_steps):
                    losses = agent.update(batch_rngs)
                look = (
                    agent.device.type == "cpu"
                    or step % DIVERGENCE_CHECK_INTERVAL == 0
                    or step == total_steps
                )
                if look:
                    q_loss = losses["q_loss"].cpu().numpy()
                    for k in np.flatnonzero(alive & ~np.isfinite(q_loss)):
                        fail(
                            k,
                            f"diverged at step {step}: losses "
                            f"{ {name: float(v[k]) for name, v in losses.items()} }",
                            total_steps - step + 1,
                        )

            if step % eval_interval == 0 or step == total_steps:
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


def _one_run_agents(bctx: BatchContext, configs: list, build: Callable) -> list:
    """The one-run agent of each member's seed, on the CPU: their weights and noise
    generators become the batch's."""
    obs_dim, act_dim, low, high = _space(bctx.shared("env_id"))
    return [
        build(obs_dim, act_dim, low, high, config, seed=seed, device="cpu", cuda_graphs=False)
        for config, seed in zip(configs, bctx.seeds)
    ]


def stacked_agent(bctx: BatchContext, configs: list, twin_q: bool) -> StackedActor:
    """The batch's agent, built member by member as the one-run path builds it."""
    agents = _one_run_agents(bctx, configs, TwinQSACAgent if twin_q else SACAgent)
    if bctx.device != "cpu":  # after the agents: building each reseeds every device
        torch.cuda.manual_seed(bctx.seeds[0] + 1)  # the batch's device stream
    if twin_q:
        return StackedTwinQAgent(agents, configs[0], bctx.device, bctx.cuda_graphs)
    return StackedSACAgent(agents, configs[0], bctx.device, bctx.cuda_graphs)


def stacked_explorer(
    bctx: BatchContext, agent: StackedActor, configs: list, guided: bool
) -> StackedExplorer:
    """SAC's explorer for the batch, or DRL-EG's over the members' shared demonstrations."""
    if not guided:
        return StackedExplorer(agent)
    demos = bctx.members[0].demos
    if demos is None:
        raise ValueError("DRL-EG needs demonstrations")
    low = (agent.policy.action_bias - agent.policy.action_scale).cpu().numpy()
    high = (agent.policy.action_bias + agent.policy.action_scale).cpu().numpy()
    return StackedGuidedExplorer(agent, configs, demos, low, high, bctx.seeds)


def _train_stacked(bctx: BatchContext, configs: list, twin_q: bool, guided: bool) -> None:
    agent = stacked_agent(bctx, configs, twin_q)
    run_stacked_off_policy(bctx, agent, stacked_explorer(bctx, agent, configs, guided))


@register_batched("sac")
def train_sac(bctx: BatchContext, configs: list[SACConfig]) -> None:
    _train_stacked(bctx, configs, twin_q=False, guided=False)


@register_batched("sac-twin-q")
def train_sac_twin_q(bctx: BatchContext, configs: list[TwinQSACConfig]) -> None:
    _train_stacked(bctx, configs, twin_q=True, guided=False)


@register_batched("drl-eg")
@register_batched("drl-eg-gmm")
def train_drl_eg(bctx: BatchContext, configs: list[DRLEGConfig]) -> None:
    _train_stacked(bctx, configs, twin_q=False, guided=True)


@register_batched("drl-eg-twin-q")
def train_drl_eg_twin_q(bctx: BatchContext, configs: list[DRLEGTwinQConfig]) -> None:
    _train_stacked(bctx, configs, twin_q=True, guided=True)


@register_batched("rlpd")
def train_rlpd(bctx: BatchContext, configs: list[RLPDConfig]) -> None:
    demos = demo_transitions_or_fail(bctx.members[0].demos)
    obs_dim, act_dim, _, _ = _space(bctx.shared("env_id"))
    demo_buffer = preloaded_buffer(demos, obs_dim, act_dim, online_capacity=0)
    agents = _one_run_agents(bctx, configs, RLPDAgent)
    if bctx.device != "cpu":  # after the agents, as for the other batches
        torch.cuda.manual_seed(bctx.seeds[0] + 1)
    agent = StackedRLPDAgent(agents, configs[0], demo_buffer, bctx.device, bctx.cuda_graphs)
    run_stacked_off_policy(bctx, agent, StackedExplorer(agent))


@register_batched("ibrl")
def train_ibrl(bctx: BatchContext, configs: list[IBRLConfig]) -> None:
    demos = bctx.members[0].demos
    if demos is None:
        raise ValueError("IBRL needs demonstrations")
    _, _, low, high = _space(bctx.shared("env_id"))
    config = configs[0]  # a batch's members differ only in their seed
    if config.imitation == "functional":  # deterministic and seed-free: one serves all
        imitations = [ImitationPolicy(config, demos, low, high, bctx.seeds[0])]
    else:
        imitations = [ImitationPolicy(config, demos, low, high, seed) for seed in bctx.seeds]
    preload = config.preload_demos and getattr(demos, "rewards", None) is not None
    agents = _one_run_agents(bctx, configs, TwinQSACAgent)  # IBRLAgent's weights and streams
    if bctx.device != "cpu":  # after the agents, as for the other batches
        torch.cuda.manual_seed(bctx.seeds[0] + 1)
    agent = StackedIBRLAgent(agents, config, imitations, demos if preload else None, bctx.device)
    run_stacked_off_policy(bctx, agent, StackedIBRLExplorer(agent))


__all__ = [
    "BatchContext",
    "StackedSACAgent",
    "StackedTwinQAgent",
    "StackedRLPDAgent",
    "StackedIBRLAgent",
    "StackedExplorer",
    "StackedGuidedExplorer",
    "stacked_explorer",
    "evaluate_members",
    "run_stacked_off_policy",
    "stacked_agent",
]
