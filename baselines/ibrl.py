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

Built on the harness's twin-Q SAC (``baselines.sac_twin_q``): its agent, networks, losses,
temperature and training loop are reused unchanged; only the next-state value of the
critic target and the choice of the executed action are IBRL's. IBRL itself is built on
TD3; SAC's entropy term stays the actor's: -alpha log pi(a'|s') of the actor's own proposal
is added whichever proposal bootstraps, so the choice between them is by Q alone.
Not implemented: IBRL's soft (Boltzmann) selection, its actor dropout and critic ensemble.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from baselines.common.buffer import Batch, ReplayBuffer
from baselines.common.context import DemoSet, TrainContext
from baselines.drl_eg import fit_neural_guider, functional_guider
from baselines.registry import register
from baselines.sac import PolicyExplorer, run_off_policy
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from envs import make_env

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
    """Twin-Q SAC whose acting and critic target choose between the actor and ``imitation``."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        config: IBRLConfig,
        seed: int,
        imitation: ImitationPolicy,
        device: str = "cpu",
        cuda_graphs: bool = True,
    ):
        super().__init__(
            obs_dim, act_dim, action_low, action_high, config, seed, device, cuda_graphs
        )
        self.imitation = imitation

    @torch.no_grad()
    def target_q(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """min_i Q'_i(s, a): the value IBRL compares proposals by."""
        return self.critics_target(obs, actions).min(dim=0).values

    @torch.no_grad()
    def propose(self, obs: np.ndarray, deterministic: bool = False) -> tuple[np.ndarray, bool]:
        """The executed action and whether the imitation policy proposed it. The actor's
        proposal is sampled (its exploration) unless ``deterministic``; ties go to the actor."""
        rl_action = super().act(obs, deterministic)
        il_action = self.imitation(obs[None])[0]
        obs_t = torch.as_tensor(obs, dtype=torch.float32, device=self.device).expand(2, -1)
        pair = torch.as_tensor(np.stack([rl_action, il_action]), device=self.device)
        q_rl, q_il = self.target_q(obs_t, pair).cpu().tolist()
        return (il_action, True) if q_il > q_rl else (rl_action, False)

    def act(self, obs: np.ndarray, deterministic: bool = False) -> np.ndarray:
        if deterministic and not self.config.eval_with_imitation:
            return super().act(obs, deterministic=True)
        return self.propose(obs, deterministic)[0]

    def target_inputs(self, batch: Batch) -> dict[str, torch.Tensor]:
        # mu(s') is computed off the gradient step (a KD-tree query on the CPU) and passed in
        next_obs = batch.next_observations.cpu().numpy()
        return {"next_il_actions": torch.as_tensor(self.imitation(next_obs))}

    def next_state_value(
        self,
        next_obs: torch.Tensor,
        next_noise: torch.Tensor,
        alpha: torch.Tensor,
        next_il_actions: torch.Tensor,
    ) -> torch.Tensor:
        """max(Q'(s', a'), Q'(s', mu(s'))) - alpha log pi(a'|s'), with a' ~ pi(.|s')."""
        next_actions, next_log_prob = self.policy.sample(next_obs, noise=next_noise)
        q_rl = self.target_q(next_obs, next_actions)
        q_il = self.target_q(next_obs, next_il_actions)
        return torch.maximum(q_rl, q_il) - alpha * next_log_prob


class IBRLExplorer(PolicyExplorer):
    """Executes IBRL's choice; a step counts as guided when the imitation action won."""

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, bool]:
        return self.agent.propose(obs)


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


@register("ibrl", IBRLConfig, needs_demos=True, gpu=True)
def train(ctx: TrainContext, config: IBRLConfig) -> ReplayBuffer:
    """IBRL (Hu et al. 2023): act and bootstrap with the better of actor and imitation policy."""
    if ctx.demos is None:
        raise ValueError("IBRL needs demonstrations")
    probe = make_env(ctx.env_id)
    obs_dim, space = probe.observation_space.shape[0], probe.action_space
    probe.close()
    act_dim = space.shape[0]
    imitation = ImitationPolicy(config, ctx.demos, space.low, space.high, ctx.seed)
    agent = IBRLAgent(
        obs_dim,
        act_dim,
        space.low,
        space.high,
        config,
        ctx.seed,
        imitation,
        device=ctx.device,
        cuda_graphs=ctx.cuda_graphs,
    )
    buffer = None
    if config.preload_demos and getattr(ctx.demos, "rewards", None) is not None:
        buffer = preloaded_buffer(
            ctx.demos, obs_dim, act_dim, min(config.buffer_size, ctx.total_steps)
        )
    return run_off_policy(ctx, agent, IBRLExplorer(agent), buffer)
