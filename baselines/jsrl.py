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
guide steps between evaluation points is its ``guided_fraction``. The stage, the best
return, H and the curriculum env's random state are checkpointed, so a resumed run goes on
with the same h.
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
from baselines.common.context import TrainContext
from baselines.common.evaluation import evaluate
from baselines.ibrl import ImitationConfig, ImitationPolicy
from baselines.registry import register
from baselines.sac import PolicyExplorer, run_off_policy
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig, build_agent
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
    """Hands each episode from the guide to the learner at step h, and moves h by the rule."""

    def __init__(
        self,
        agent: TwinQSACAgent,
        guide: ImitationPolicy,
        config: JSRLConfig,
        curriculum_env: gym.Env,
        horizon: int,
        eval_episodes: int,
    ):
        super().__init__(agent)
        self.guide, self.config, self.env = guide, config, curriculum_env
        self.horizon, self.eval_episodes = horizon, eval_episodes
        self.stage, self.best = 0, None
        self.t, self.episode_h = 0, self.h

    @property
    def h(self) -> int:
        return guide_steps(self.horizon, self.stage, self.config.curriculum_stages)

    def act_guide(self, obs: np.ndarray) -> np.ndarray:
        return self.guide(obs[None])[0]

    def episode_start(self) -> None:
        self.t, self.episode_h = 0, self.h  # h changes only between episodes

    def choose(self, obs: np.ndarray) -> tuple[np.ndarray, bool]:
        guided = self.t < self.episode_h
        self.t += 1
        return (self.act_guide(obs), True) if guided else (self.agent.act(obs), False)

    def after_eval(self, mean_return: float) -> None:
        if self.h == 0:  # the curriculum is over
            return None
        if self.config.curriculum_eval == "jump-start":
            learner = lambda obs: self.agent.act(obs, deterministic=True)  # noqa: E731
            mean_return = float(
                np.mean(
                    jump_start_returns(
                        self.env, self.act_guide, learner, self.h, self.eval_episodes
                    )
                )
            )
        if advances(mean_return, self.best, self.config.tolerance):
            self.stage += 1
        self.best = mean_return if self.best is None else max(self.best, mean_return)
        return None

    def state_dict(self) -> dict[str, Any]:
        return {
            "stage": self.stage,
            "h": self.h,
            "best": self.best,
            "horizon": self.horizon,
            "curriculum_env_rng": env_rng_state(self.env),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.stage, self.best, self.horizon = state["stage"], state["best"], state["horizon"]
        restore_env_rng(self.env, state["curriculum_env_rng"])


@register("jsrl", JSRLConfig, needs_demos=True, gpu=True)
def train(ctx: TrainContext, config: JSRLConfig) -> ReplayBuffer:
    """JSRL (Uchendu et al. 2023): a guide acts for the first h steps, h falls by a curriculum."""
    if ctx.demos is None:
        raise ValueError("JSRL needs demonstrations")
    agent = build_agent(ctx, config)
    curriculum_env = make_env(ctx.env_id, seed=ctx.seed + CURRICULUM_SEED_OFFSET)
    space = curriculum_env.action_space
    guide = ImitationPolicy(config, ctx.demos, space.low, space.high, ctx.seed)
    horizon = config.guide_horizon or measure_horizon(
        curriculum_env, lambda obs: guide(obs[None])[0], config.horizon_episodes
    )
    explorer = JumpStartExplorer(agent, guide, config, curriculum_env, horizon, ctx.eval_episodes)
    try:
        return run_off_policy(ctx, agent, explorer)
    finally:
        curriculum_env.close()
