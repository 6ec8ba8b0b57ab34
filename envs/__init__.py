"""Environment adapters: one ``make_env`` for the paper's tasks and dm-control tasks.

Every adapter returns a Gymnasium env whose observations are flat float32 vectors,
whose actions live in a float32 box with the underlying env's bounds, and which keeps
termination (a true end of the task) apart from truncation (a time limit).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

# dm-control picks an OpenGL backend at import; the harness never renders, and an
# attempt to open GLFW without a display only produces noise.
os.environ.setdefault("MUJOCO_GL", "disable")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402


@dataclass(frozen=True)
class EnvSpec:
    """One row of the environment table (Table 1 of the paper is drawn from it)."""

    env_id: str
    suite: str  # "classic", "mujoco" or "dm_control"
    obs_dim: int
    act_dim: int
    max_episode_steps: int
    reward_kind: str  # "dense" or "sparse"
    paper_env_id: str | None = None  # the id the paper used, where it used this task
    paper_obs_dim: int | None = None
    paper_act_dim: int | None = None


ENV_SPECS: dict[str, EnvSpec] = {
    spec.env_id: spec
    for spec in [
        EnvSpec(
            "MountainCarContinuous-v0",
            "classic",
            2,
            1,
            999,
            "sparse",
            "MountainCarContinuous-v0",
            2,
            1,
        ),
        EnvSpec("Hopper-v5", "mujoco", 11, 3, 1000, "dense", "Hopper-v2", 11, 3),
        EnvSpec("Walker2d-v5", "mujoco", 17, 6, 1000, "dense", "Walker2d-v2", 17, 6),
        EnvSpec("HalfCheetah-v5", "mujoco", 17, 6, 1000, "dense", "HalfCheetah-v2", 17, 6),
        # Ant-v2 exposed 111 dims (with always-zero contact forces); Ant-v5 has 105.
        EnvSpec("Ant-v5", "mujoco", 105, 8, 1000, "dense", "Ant-v2", 111, 8),
        EnvSpec("dm_control/cartpole-swingup-v0", "dm_control", 5, 1, 1000, "dense"),
        EnvSpec("dm_control/cartpole-swingup_sparse-v0", "dm_control", 5, 1, 1000, "sparse"),
        EnvSpec("dm_control/ball_in_cup-catch-v0", "dm_control", 8, 2, 1000, "sparse"),
        EnvSpec("dm_control/walker-walk-v0", "dm_control", 24, 6, 1000, "dense"),
    ]
}

PAPER_ENV_IDS: tuple[str, ...] = tuple(s.env_id for s in ENV_SPECS.values() if s.paper_env_id)


class UnknownEnvError(ValueError):
    """Raised for an env id outside the spec table."""


def env_spec(env_id: str) -> EnvSpec:
    """The spec row of ``env_id``; raises :class:`UnknownEnvError` listing the known ids."""
    try:
        return ENV_SPECS[env_id]
    except KeyError:
        known = ", ".join(ENV_SPECS)
        raise UnknownEnvError(f"unknown env '{env_id}'; known envs: {known}") from None


class FlatFloat32Env(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Flattens dict observations into one float32 vector and exposes a float32 action box.

    The action is cast back to the wrapped env's dtype before stepping; observations are
    flattened in the (sorted) key order of the wrapped observation space, so the layout
    is fixed whatever order the underlying env builds its dict in.
    """

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self._inner_obs_space = env.observation_space
        self._inner_is_box = isinstance(env.observation_space, gym.spaces.Box)
        flat = gym.spaces.flatten_space(env.observation_space)
        self.observation_space = gym.spaces.Box(
            low=flat.low.astype(np.float32), high=flat.high.astype(np.float32), dtype=np.float32
        )
        inner_act = env.action_space
        assert isinstance(inner_act, gym.spaces.Box), "only continuous-action envs are supported"
        self._inner_act_dtype = inner_act.dtype
        self.action_space = gym.spaces.Box(
            low=inner_act.low.astype(np.float32),
            high=inner_act.high.astype(np.float32),
            dtype=np.float32,
        )

    def _flat(self, obs: Any) -> np.ndarray:
        if self._inner_is_box:  # one cast: the same values as flatten, then a cast
            return np.array(obs, dtype=np.float32).reshape(-1)  # a copy, as flatten makes
        return np.asarray(gym.spaces.flatten(self._inner_obs_space, obs), dtype=np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict | None = None
    ) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(seed=seed, options=options)
        return self._flat(obs), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        action = np.asarray(action, dtype=self._inner_act_dtype)
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._flat(obs), float(reward), bool(terminated), bool(truncated), info


def make_env(env_id: str, seed: int | None = None) -> gym.Env:
    """Build the adapter for ``env_id``, seeded when ``seed`` is given.

    The seed is applied by a first ``reset(seed=seed)`` (so the env's RNG is fixed) and to
    the action space; later resets without a seed continue that RNG stream.
    """
    spec = env_spec(env_id)
    if spec.suite == "dm_control":
        import shimmy  # noqa: F401  (registers the dm_control/* ids)

    inner = gym.make(env_id, max_episode_steps=spec.max_episode_steps)
    env = FlatFloat32Env(inner)
    if seed is not None:
        env.reset(seed=seed)
        env.action_space.seed(seed)
    return env


__all__ = ["ENV_SPECS", "PAPER_ENV_IDS", "EnvSpec", "UnknownEnvError", "env_spec", "make_env"]
