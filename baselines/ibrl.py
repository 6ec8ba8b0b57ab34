"""IBRL: Imitation Bootstrapped Reinforcement Learning (Hu et al. 2023, arXiv:2311.02198).

An imitation policy mu(s), fixed before RL starts, proposes an action beside the RL actor's,
twice per step:

    acting     a = argmax_{a in {a_rl, mu(s)}} Q(s, a),        a_rl ~ pi(.|s) (its exploration)
    bootstrap  y = r + gamma * (1 - terminated) * (max_{a in {a', mu(s')}} Q(s', a)
                                                   - alpha * log pi(a'|s')),   a' ~ pi(.|s')

with Q = min_i Q'_i over the target critics in both places, as IBRL's code compares its
proposals. Evaluation runs the same selection with the actor's deterministic action (IBRL's
deployed policy is the pair); ``eval_with_imitation=False`` evaluates the actor alone.

The imitation policy is a setting: ``functional`` is DRL-EG's functional guider without
noise (the nearest demonstration's action, everywhere, with no discriminator), the clean
comparison of "act with the demonstrations" against DRL-EG's "guide only near them";
``bc`` is an MLP regressed on the demonstration pairs before RL, as in IBRL (DRL-EG's neural
guider, reused). Where the demonstration file holds transitions, they are preloaded into
the replay buffer as IBRL does (``preload_demos``); a file of pairs alone trains without.

Built on the harness's twin-Q SAC (``baselines.sac_twin_q``): its networks, losses,
temperature and training loop are reused unchanged; only the next-state value of the
critic target and the choice of the executed action are IBRL's. IBRL itself is built on
TD3; SAC's entropy term stays the actor's: -alpha log pi(a'|s') of the actor's own proposal
is added whichever proposal bootstraps, so the choice between them is by Q alone.
Not implemented: IBRL's soft (Boltzmann) selection, its actor dropout and critic ensemble.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.context import BatchContext, DemoSet
from baselines.common.stacked import StackedReplay
from baselines.contract import FULL_STEP
from baselines.drl_eg import fit_neural_guider, functional_guider
from baselines.offpolicy import PolicyExplorer, action_space, train_members
from baselines.registry import register
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig

IMITATION_POLICIES = ("functional", "bc")


@dataclass
class ImitationConfig:
    """Which imitation policy proposes actions, and how the BC one is fitted."""

    imitation: str = "functional"  # "functional" (nearest demo action) or "bc" (MLP)
    bc_steps: int = 2000  # Adam steps of the BC regression (as DRL-EG's neural guider)
    bc_hidden: tuple[int, ...] = (256, 256)

    def validate_imitation(self) -> None:
        self.bc_hidden = tuple(int(w) for w in self.bc_hidden)
        if self.imitation not in IMITATION_POLICIES:
            raise ValueError(
                f"imitation must be one of {IMITATION_POLICIES}, got '{self.imitation}'"
            )
        if self.bc_steps < 0:
            raise ValueError("bc_steps must be >= 0")


@dataclass
class IBRLConfig(TwinQSACConfig, ImitationConfig):
    """Twin-Q SAC's hyperparameters plus the imitation policy."""

    preload_demos: bool = True  # demonstration transitions start in the replay buffer
    eval_with_imitation: bool = True  # evaluate IBRL's pair (the paper) or the actor alone

    def __post_init__(self) -> None:
        super().__post_init__()
        self.validate_imitation()


class ImitationPolicy:
    """mu(s) for a batch of states: the nearest demonstration's action (DRL-EG's functional
    guider with sigma = 0), or a BC regression of the pairs; clipped to the action box.
    Deterministic, so it is refitted identically on resume and needs no checkpoint."""

    def __init__(
        self, config: ImitationConfig, demos: DemoSet, low: np.ndarray, high: np.ndarray, seed: int
    ):
        self.kind, self.low, self.high = config.imitation, low, high
        self.actions = np.asarray(demos.actions, dtype=np.float64)
        self.rng = np.random.default_rng(0)  # functional_guider's; sigma = 0 leaves it unused
        if self.kind == "functional":
            self.tree = cKDTree(np.asarray(demos.observations, dtype=np.float64))
        else:
            self.net = fit_neural_guider(demos, config.bc_hidden, config.bc_steps, seed)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """Actions (n, act_dim) float32 for states (n, obs_dim)."""
        states = np.asarray(states, dtype=np.float64)
        if self.kind == "functional":
            _, index = self.tree.query(states)
            return functional_guider(self.actions, index, 0.0, self.rng, self.low, self.high)
        with torch.no_grad():
            mean = self.net(torch.as_tensor(states, dtype=torch.float32)).numpy()
        return np.clip(mean, self.low, self.high).astype(np.float32)


class IBRLAgent(TwinQSACAgent):
    """IBRL for N members: twin-Q SAC's networks; each member acts and bootstraps with the
    higher-valued (by its target critics) of its actor's proposal and its imitation
    policy's, and its replay starts with the demonstration transitions. The imitation
    actions come from the CPU (a KD-tree query or a BC net), so no step is a CUDA graph."""

    def __init__(
        self,
        seeds: list[int],
        env_id: str,
        config: IBRLConfig,
        imitations: list[ImitationPolicy],
        demos: Any,
        device: str = "cpu",
    ):
        self.imitations = imitations
        self.demos = demos  # a DemoSet with transitions to preload, or None
        super().__init__(seeds, env_id, config, device, cuda_graphs=False)

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
                self.member_noise(1)
                if self.device.type == "cpu"
                else torch.randn((self.members, 1, self.act_dim), device=self.device)
            )
            rl_action, _ = self.policy.sample(obs_t, noise=noise.to(self.device))
        il_action = torch.from_numpy(self.imitation_actions(obs[:, None, :])).to(self.device)
        pair = torch.cat([rl_action, il_action], dim=1)  # (N, 2, act_dim)
        q = self.target_q(obs_t.expand(-1, 2, -1), pair)  # (N, 2)
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
        """Each member's replay, the demonstration transitions first."""
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

    def step_inputs(self, batch: Batch, kind: str = FULL_STEP) -> dict[str, torch.Tensor]:
        """mu(s'), computed off the gradient step (a KD-tree query on the CPU)."""
        next_il = self.imitation_actions(batch.next_observations.cpu().numpy())
        return {"next_il_actions": torch.from_numpy(next_il).to(self.device)}

    def bootstrap_q(
        self, next_obs: torch.Tensor, next_actions: torch.Tensor, next_il_actions: torch.Tensor
    ) -> torch.Tensor:
        """max(Q'(s', a'), Q'(s', mu(s'))) per member, a' ~ pi(.|s')."""
        q_rl = self.target_q(next_obs, next_actions)
        return torch.maximum(q_rl, self.target_q(next_obs, next_il_actions))


class IBRLExplorer(PolicyExplorer):
    """IBRL's choice for N members; a step counts as guided where the imitation action won."""

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.agent.propose(obs, deterministic=False)


def preloaded_buffer(
    demos: DemoSet, obs_dim: int, act_dim: int, online_capacity: int
) -> ReplayBuffer:
    """A replay buffer holding the demonstration transitions first, with room for
    ``online_capacity`` more; the ring overwrites the demonstrations first once it is full."""
    n = len(demos.observations)
    buffer = ReplayBuffer(obs_dim, act_dim, n + online_capacity)
    for i in range(n):
        buffer.add(
            demos.observations[i],
            demos.actions[i],
            demos.rewards[i],
            demos.next_observations[i],
            bool(demos.terminated[i]),
        )
    return buffer


@register("ibrl", IBRLConfig, needs_demos=True, gpu=True, batchable=True)
def train(bctx: BatchContext, configs: list[IBRLConfig]) -> ReplayBuffer:
    """IBRL (Hu et al. 2023): act and bootstrap with the better of actor and imitation policy."""
    demos = bctx.members[0].demos
    if demos is None:
        raise ValueError("IBRL needs demonstrations")
    env_id = bctx.shared("env_id")
    _, _, low, high = action_space(env_id)
    config = configs[0]  # a batch's members differ only in their seed
    if config.imitation == "functional":  # deterministic and seed-free: one serves all
        imitations = [ImitationPolicy(config, demos, low, high, bctx.seeds[0])]
    else:
        imitations = [ImitationPolicy(config, demos, low, high, seed) for seed in bctx.seeds]
    preload = config.preload_demos and getattr(demos, "rewards", None) is not None
    agent = IBRLAgent(
        bctx.seeds, env_id, config, imitations, demos if preload else None, bctx.device
    )
    return train_members(bctx, agent, IBRLExplorer)
