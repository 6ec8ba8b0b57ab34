"""Deterministic-policy evaluation, the performance measure of every curve."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

# Evaluation episodes use their own env instance, seeded apart from the training env.
EVAL_SEED_OFFSET = 10_000


def evaluate(env: gym.Env, act: Callable[[np.ndarray], np.ndarray], episodes: int) -> list[float]:
    """Run ``episodes`` full episodes with ``act`` and return each undiscounted return."""
    returns = []
    for _ in range(episodes):
        obs, _ = env.reset()
        done, total = False, 0.0
        while not done:
            obs, reward, terminated, truncated, _ = env.step(act(obs))
            total += reward
            done = terminated or truncated
        returns.append(total)
    return returns
