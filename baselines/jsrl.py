"""JSRL: Jump-Start Reinforcement Learning (Uchendu et al. 2023, arXiv:2204.02372), curriculum.

Two policies share every training episode: a fixed guide acts for its first h steps, the
learner (twin-Q SAC, ``baselines.sac_twin_q``) for the rest, so the learner starts from
states the guide reaches, ever closer to the start as h falls:

    a_t = guide(s_t)        for t < h  (h fixed when the episode starts)
    a_t ~ pi(.|s_t)         for t >= h

Every transition, the guide's and the learner's, goes to the learner's replay buffer.

Curriculum: h takes the values H, H (n-1)/n, ..., H/n, 0 (rounded) over n =
``curriculum_stages`` stages. H is the guide's horizon: ``guide_horizon``, or where that is
0, the median length of ``horizon_episodes`` episodes of the guide alone (at most the env's
time limit; the median, since a guide that now and then stalls, as the noise-free
nearest-neighbour guide does on MountainCar in about one episode in five, would make the
longest the time limit). After each evaluation the combined policy (the guide for h steps,
then the learner's deterministic action) is evaluated on its own env; with R its mean
return and B the best such R before it (over every stage so far), the stage advances when

    R >= B - tolerance * |B|

and B becomes max(B, R); the first evaluation only sets B. That is JSRL's curriculum (move
on once the jump-started policy does as well as the best seen, within a tolerance); the
relative tolerance and the first evaluation's role are the harness's. With
``curriculum_eval="learner"`` the rule judges the learner's own evaluation instead, which
does not depend on h (so h then falls whenever the learner does not get worse). Once h is
0 the run is twin-Q SAC.

The guide is an imitation policy of the demonstrations (``baselines.ibrl.ImitationPolicy``):
by default DRL-EG's functional guider without noise, ``imitation="bc"`` for an MLP
regressed on the pairs; JSRL's guides were pretrained policies. The curve is the learner's
own deterministic evaluation (no guide steps), as for every other algorithm; the share of
guide steps between evaluation points is its ``guided_fraction``. Each member of a seed
batch has its own guide, curriculum env, H, stage and best return. The stage, the best
return, H, the step within the episode and the curriculum env's random state are
checkpointed, so a resumed run goes on with the same h.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from baselines.common.buffer import ReplayBuffer
from baselines.common.checkpoint import env_rng_state, restore_env_rng
from baselines.common.context import BatchContext
from baselines.common.evaluation import evaluate
from baselines.ibrl import ImitationConfig, ImitationPolicy
from baselines.offpolicy import (
    OffPolicyAgent,
    PolicyExplorer,
    action_space,
    run_off_policy,
    seed_device_stream,
)
from baselines.registry import register
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from envs import make_env

CURRICULUM_EVALS = ("jump-start", "learner")
# the curriculum's own env, apart from training seeds (0, 1, ...) and evaluation (10,000 + seed)
CURRICULUM_SEED_OFFSET = 20_000


@dataclass
class JSRLConfig(TwinQSACConfig, ImitationConfig):
    """Twin-Q SAC's hyperparameters plus the guide and its curriculum."""

    curriculum_stages: int = 10  # n: h falls from H to 0 in n steps
    tolerance: float = 0.05  # advance when R >= B - tolerance * |B|
    guide_horizon: int = 0  # H; 0: measured from the guide's own episodes
    horizon_episodes: int = 5
    curriculum_eval: str = "jump-start"  # or "learner"

    def __post_init__(self) -> None:
        super().__post_init__()
        self.validate_imitation()
        if (
            self.curriculum_stages < 1
            or self.tolerance < 0
            or self.guide_horizon < 0
            or self.horizon_episodes < 1
        ):
            raise ValueError(
                "curriculum_stages and horizon_episodes must be >= 1, "
                "tolerance and guide_horizon >= 0"
            )
        if self.curriculum_eval not in CURRICULUM_EVALS:
            raise ValueError(f"curriculum_eval must be one of {CURRICULUM_EVALS}")


def guide_steps(horizon: int, stage: int, stages: int) -> int:
    """h of a curriculum stage: H at stage 0, falling linearly to 0 at stage ``stages``."""
    return round(horizon * max(stages - stage, 0) / stages)


def advances(mean_return: float, best: float | None, tolerance: float) -> bool:
    """JSRL's rule: the stage advances when R is within ``tolerance`` (relative) of the best
    R before it; the first evaluation has nothing to compare with."""
    return best is not None and mean_return >= best - tolerance * abs(best)


def jump_start_returns(
    env: gym.Env,
    guide: Callable[[np.ndarray], np.ndarray],
    learner: Callable[[np.ndarray], np.ndarray],
    h: int,
    episodes: int,
) -> list[float]:
    """Returns of episodes where ``guide`` acts for the first h steps and ``learner`` after."""
    returns = []
    for _ in range(episodes):
        t = itertools.count()
        returns += evaluate(env, lambda obs: guide(obs) if next(t) < h else learner(obs), 1)
    return returns


def measure_horizon(env: gym.Env, guide: Callable[[np.ndarray], np.ndarray], episodes: int) -> int:
    """The median length, in steps, of ``episodes`` episodes of ``guide`` alone."""
    lengths = []
    for _ in range(episodes):
        steps = itertools.count()

        def counted(obs: np.ndarray) -> np.ndarray:
            next(steps)
            return guide(obs)

        evaluate(env, counted, 1)
        lengths.append(next(steps))
    return round(float(np.median(lengths)))


class JumpStartExplorer(PolicyExplorer):
    """Hands each member's episodes from its guide to its learner at step h, and moves each
    member's h by the rule."""

    def __init__(
        self,
        agent: OffPolicyAgent,
        guides: list[ImitationPolicy],
        config: JSRLConfig,
        curriculum_envs: list[gym.Env],
        horizons: list[int],
        eval_episodes: int,
    ):
        super().__init__(agent)
        self.guides, self.config, self.envs = guides, config, curriculum_envs
        self.horizons, self.eval_episodes = list(horizons), eval_episodes
        n = len(guides)
        self.stage = np.zeros(n, dtype=np.int64)
        self.best: list[float | None] = [None] * n
        self.t = np.zeros(n, dtype=np.int64)  # steps into each member's episode
        self.episode_h = np.array([self.h(k) for k in range(n)])

    def h(self, k: int) -> int:
        return guide_steps(self.horizons[k], int(self.stage[k]), self.config.curriculum_stages)

    def episode_start(self, started: np.ndarray) -> None:
        for k in np.flatnonzero(started):  # h changes only between episodes
            self.t[k], self.episode_h[k] = 0, self.h(k)

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        guided = self.t < self.episode_h
        self.t += 1
        actions = self.agent.act(obs, need=~guided)
        for k in np.flatnonzero(guided):
            actions[k] = self.guides[k](obs[k][None])[0]
        return actions, guided

    def after_eval(self, k: int, mean_return: float) -> None:
        if self.h(k) == 0:  # member k's curriculum is over
            return None
        if self.config.curriculum_eval == "jump-start":
            guide = lambda obs: self.guides[k](obs[None])[0]  # noqa: E731
            learner = lambda obs: self.agent.act_member_deterministic(k, obs)  # noqa: E731
            returns = jump_start_returns(
                self.envs[k], guide, learner, self.h(k), self.eval_episodes
            )
            mean_return = float(np.mean(returns))
        if advances(mean_return, self.best[k], self.config.tolerance):
            self.stage[k] += 1
        self.best[k] = mean_return if self.best[k] is None else max(self.best[k], mean_return)
        return None

    def state_dict(self) -> dict[str, Any]:
        return {
            "stage": self.stage.copy(),
            "best": list(self.best),
            "horizons": list(self.horizons),
            "t": self.t.copy(),
            "episode_h": self.episode_h.copy(),
            "curriculum_env_rngs": [env_rng_state(env) for env in self.envs],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.stage, self.best = state["stage"].copy(), list(state["best"])
        self.horizons = list(state["horizons"])
        self.t, self.episode_h = state["t"].copy(), state["episode_h"].copy()
        for env, rng in zip(self.envs, state["curriculum_env_rngs"], strict=True):
            restore_env_rng(env, rng)


@register("jsrl", JSRLConfig, needs_demos=True, gpu=True, batchable=True)
def train(bctx: BatchContext, configs: list[JSRLConfig]) -> ReplayBuffer:
    """JSRL (Uchendu et al. 2023): a guide acts for the first h steps, h falls by a curriculum."""
    demos = bctx.members[0].demos
    if demos is None:
        raise ValueError("JSRL needs demonstrations")
    env_id, config = bctx.shared("env_id"), configs[0]
    agent = TwinQSACAgent(bctx.seeds, env_id, config, bctx.device, bctx.cuda_graphs)
    seed_device_stream(bctx)
    _, _, low, high = action_space(env_id)
    envs = [make_env(env_id, seed=seed + CURRICULUM_SEED_OFFSET) for seed in bctx.seeds]
    try:
        guides = [ImitationPolicy(config, demos, low, high, seed) for seed in bctx.seeds]
        horizons = [
            config.guide_horizon
            or measure_horizon(env, lambda obs, g=guide: g(obs[None])[0], config.horizon_episodes)
            for env, guide in zip(envs, guides)
        ]
        eval_episodes = bctx.shared("eval_episodes")
        explorer = JumpStartExplorer(agent, guides, config, envs, horizons, eval_episodes)
        return run_off_policy(bctx, agent, explorer)
    finally:
        for env in envs:
            env.close()
