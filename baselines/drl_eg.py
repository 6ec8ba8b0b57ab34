"""DRL-EG: SAC whose exploration is guided by a few demonstrations (Lin et al., the paper).

A discriminator D(s) decides whether a state is close enough to the demonstrations to be
guided; if so, and while the demonstrations still beat the policy (R_demo > R_pi), the
executed action comes from the guider G(s) instead of the policy. The functional forms
used in the paper's experiments (eqs. 11 and 12):

    D(s) = 1  if  min_i ||s - s_i^d||_2 <= T2,  else 0
    G(s) = a_{i*}^d + xi,  i* = argmin_i ||s - s_i^d||_2,  xi ~ N(0, sigma^2)

The paper's other two forms are selectable by configuration: a GMM discriminator (eq. 10:
guide when the fitted density of s exceeds T) and a neural guider (an MLP regressed on the
demonstration pairs, plus the same noise). Everything else is SAC (``baselines.sac``): the
same seed gives the same initial weights, and the executed action, guided or not, is what
is stored in the replay buffer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree
from sklearn.mixture import GaussianMixture

from baselines.common.buffer import ReplayBuffer
from baselines.common.context import BatchContext, DemoSet
from baselines.common.networks import mlp
from baselines.offpolicy import OffPolicyAgent, PolicyExplorer, train_members
from baselines.registry import register
from baselines.sac import SACAgent, SACConfig
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig

DISCRIMINATORS = ("functional", "gmm")
GUIDERS = ("functional", "neural")


@dataclass
class GuidanceConfig:
    """What the paper leaves unset in D(s) and G(s): T2, sigma, K, T, the MLP."""

    discriminator: str = "functional"  # "functional" (eq. 11) or "gmm" (eq. 10)
    guider: str = "functional"  # "functional" (eq. 12) or "neural"
    guide_threshold: float = 0.05  # T2, in the raw state units of the env
    guide_noise_std: float = 0.1  # sigma of the guider's Gaussian noise
    gmm_components: int = 8  # K
    # T is set as this quantile of the demonstration states' own GMM densities, so that
    # one value means the same thing in every env (0.05: 95% of demo states are guided).
    gmm_threshold_quantile: float = 0.05
    neural_guider_steps: int = 2000  # regression steps of the neural guider
    neural_guider_hidden: tuple[int, ...] = (256, 256)

    def validate_guidance(self) -> None:
        self.neural_guider_hidden = tuple(int(w) for w in self.neural_guider_hidden)
        if self.guide_threshold < 0 or self.guide_noise_std < 0:
            raise ValueError("guide_threshold (T2) and guide_noise_std (sigma) must be >= 0")
        if self.discriminator not in DISCRIMINATORS or self.guider not in GUIDERS:
            raise ValueError(
                f"discriminator must be one of {DISCRIMINATORS} and guider one of {GUIDERS}"
            )
        if not 0.0 <= self.gmm_threshold_quantile <= 1.0 or self.gmm_components < 1:
            raise ValueError("gmm_threshold_quantile must be in [0, 1] and gmm_components >= 1")


@dataclass
class DRLEGConfig(SACConfig, GuidanceConfig):
    """The paper's SAC hyperparameters plus the guidance settings."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.validate_guidance()


@dataclass
class DRLEGTwinQConfig(TwinQSACConfig, GuidanceConfig):
    """Twin-Q, learned-temperature SAC's hyperparameters plus the guidance settings."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.validate_guidance()


@dataclass
class DRLEGGMMConfig(DRLEGConfig):
    discriminator: str = "gmm"


def nearest_demo(demo_states: np.ndarray, state: np.ndarray) -> tuple[float, int]:
    """Euclidean distance to, and index of, the demonstration state nearest ``state``, by
    brute force: the reference the guider's KD-tree is tested against."""
    squared = np.einsum("ij,ij->i", demo_states - state, demo_states - state)
    index = int(np.argmin(squared))
    return float(np.sqrt(squared[index])), index


def demo_state_spacing(demo_states: np.ndarray) -> float:
    """Median distance from a demonstration state to its nearest other one.

    Consecutive states of a demonstrated trajectory are about one step apart, so a T2 of this
    size guides states within about a step of the demonstrations. It sets T2 where the paper
    gives no value, in the env's own state units (a fixed number is meaningless across an
    11-dimensional Hopper and a 105-dimensional Ant).
    """
    if len(demo_states) < 2:
        raise ValueError("the spacing of demonstration states needs at least two of them")
    distances, _ = cKDTree(demo_states).query(demo_states, k=2)
    return float(np.median(distances[:, 1]))


def functional_discriminator(distance: float, threshold: float) -> bool:
    """D(s) of eq. 11: guide when the nearest demonstration state is within T2.

    T2 = 0 switches guidance off. Read literally, eq. 11 would still guide a state identical
    to a demonstration state, and such states occur: MountainCar's left wall (-1.2, 0),
    where the rule's episodes and an untrained agent both come to rest.
    """
    return threshold > 0 and distance <= threshold


def functional_guider(
    demo_actions: np.ndarray,
    index: int,
    noise_std: float,
    rng: np.random.Generator,
    low: np.ndarray,
    high: np.ndarray,
) -> np.ndarray:
    """G(s) of eq. 12: the nearest demonstration's action plus N(0, sigma^2), clipped to the box."""
    action = demo_actions[index] + noise_std * rng.standard_normal(demo_actions.shape[1])
    return np.clip(action, low, high).astype(np.float32)


def fit_gmm(
    demo_states: np.ndarray, components: int, threshold_quantile: float, seed: int
) -> tuple[GaussianMixture, float]:
    """EM fit of the state density (eq. 10) and the log-density threshold log T."""
    gmm = GaussianMixture(
        n_components=min(components, len(demo_states)),
        covariance_type="full",
        reg_covar=1e-4,
        random_state=seed,
    )
    gmm.fit(demo_states)
    log_threshold = float(np.quantile(gmm.score_samples(demo_states), threshold_quantile))
    return gmm, log_threshold


def gmm_discriminator(gmm: GaussianMixture, state: np.ndarray, log_threshold: float) -> bool:
    """D(s) of eq. 10 in log space: guide when log p(s) > log T."""
    return float(gmm.score_samples(state[None, :])[0]) > log_threshold


def fit_neural_guider(
    demos: DemoSet, hidden: tuple[int, ...], steps: int, seed: int
) -> torch.nn.Module:
    """An MLP s -> a regressed on the demonstration pairs (mean squared error)."""
    generator = torch.Generator().manual_seed(seed)
    states = torch.as_tensor(np.asarray(demos.observations, dtype=np.float32))
    actions = torch.as_tensor(np.asarray(demos.actions, dtype=np.float32))
    # keep the global CPU stream (SAC's weights) untouched; devices=[] and the CPU generator
    # alone, so that a CPU run on a GPU machine starts no CUDA context
    with torch.random.fork_rng(devices=[]):
        torch.random.default_generator.manual_seed(seed)
        net = mlp(states.shape[1], actions.shape[1], hidden)
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)
    for _ in range(steps):
        idx = torch.randint(0, len(states), (min(256, len(states)),), generator=generator)
        loss = (net(states[idx]) - actions[idx]).pow(2).sum(-1).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return net.eval()


class GuidedExplorer(PolicyExplorer):
    """Algorithm 1's choice of action for N members: member k takes its guider's action
    while its R_demo > R_pi and D(s_k) = 1. One KD-tree of the shared demonstrations answers
    all N states in one query; each member keeps its own T2, sigma, guider stream and gate."""

    def __init__(
        self,
        agent: OffPolicyAgent,
        configs: list,
        demos: DemoSet,
        low: np.ndarray,
        high: np.ndarray,
        seeds: list[int],
    ):
        super().__init__(agent)
        self.configs, self.low, self.high = configs, low, high
        self.states = np.asarray(demos.observations, dtype=np.float64)
        self.demo_actions = np.asarray(demos.actions, dtype=np.float64)
        # exact nearest neighbour in O(log n): the paper's "huge number" of demonstrations
        # (1M pairs) costs about what 1000 do; one tree answers every member
        self.tree = cKDTree(self.states)
        self.rngs = [np.random.default_rng([seed, 2]) for seed in seeds]  # apart from SAC's
        # each member fits its GMM or guider MLP from its own seed
        self.gmms = [
            fit_gmm(self.states, c.gmm_components, c.gmm_threshold_quantile, seed)
            if c.discriminator == "gmm"
            else None
            for c, seed in zip(configs, seeds)
        ]
        self.nets = [
            fit_neural_guider(demos, c.neural_guider_hidden, c.neural_guider_steps, seed)
            if c.guider == "neural"
            else None
            for c, seed in zip(configs, seeds)
        ]
        self.thresholds = np.array([c.guide_threshold for c in configs])
        self.demo_return = demos.mean_return
        self.policy_returns = np.zeros(len(configs))  # Algorithm 1: R_pi <- 0 before testing

    def decide(self, obs: np.ndarray, gate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(s) for the members in ``gate``, and each nearest demonstration's index (-1
        where not searched or not guided)."""
        n = len(obs)
        guided = np.zeros(n, dtype=bool)
        index = np.full(n, -1)
        functional = np.array([c.discriminator == "functional" for c in self.configs]) & gate
        if functional.any():
            # only a neighbour within T2 matters, so the search stops there: a state far
            # from every demonstration, the common case, costs almost nothing (the bound is
            # strict and squared: widen it a hair, then test <= T2)
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


def guided_explorer(bctx: BatchContext, agent: OffPolicyAgent, configs: list) -> GuidedExplorer:
    """DRL-EG's explorer for the batch, over the members' shared demonstrations."""
    demos = bctx.members[0].demos
    if demos is None:
        raise ValueError("DRL-EG needs demonstrations")
    low = (agent.policy.action_bias - agent.policy.action_scale).cpu().numpy()
    high = (agent.policy.action_bias + agent.policy.action_scale).cpu().numpy()
    return GuidedExplorer(agent, configs, demos, low, high, bctx.seeds)


def _train_guided(bctx: BatchContext, configs: list, agent_cls: type) -> ReplayBuffer:
    agent = agent_cls(bctx.seeds, bctx.shared("env_id"), configs[0], bctx.device, bctx.cuda_graphs)
    return train_members(bctx, agent, lambda built: guided_explorer(bctx, built, configs))


# the batched explorer reads T2 and sigma per member: a T2 sweep trains as one seed batch
PER_MEMBER_GUIDANCE = ("guide_threshold", "guide_noise_std")


@register(
    "drl-eg",
    DRLEGConfig,
    needs_demos=True,
    gpu=True,
    batchable=True,
    per_member_settings=PER_MEMBER_GUIDANCE,
)
def train(bctx: BatchContext, configs: list[DRLEGConfig]) -> ReplayBuffer:
    """DRL-EG with the functional D(s) and G(s) of the paper, on top of SAC."""
    return _train_guided(bctx, configs, SACAgent)


@register(
    "drl-eg-gmm",
    DRLEGGMMConfig,
    needs_demos=True,
    gpu=True,
    batchable=True,
    per_member_settings=PER_MEMBER_GUIDANCE,
)
def train_gmm(bctx: BatchContext, configs: list[DRLEGGMMConfig]) -> ReplayBuffer:
    """DRL-EG with the GMM discriminator (density above T) and the functional guider."""
    return _train_guided(bctx, configs, SACAgent)


@register(
    "drl-eg-twin-q",
    DRLEGTwinQConfig,
    needs_demos=True,
    gpu=True,
    batchable=True,
    per_member_settings=PER_MEMBER_GUIDANCE,
)
def train_twin_q(bctx: BatchContext, configs: list[DRLEGTwinQConfig]) -> ReplayBuffer:
    """DRL-EG's guidance on twin-Q, learned-temperature SAC (not the paper's; SB3's SAC)."""
    return _train_guided(bctx, configs, TwinQSACAgent)
