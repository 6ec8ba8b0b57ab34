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


class TrainingReturns:
    """The undiscounted returns of the training episodes of ``n`` envs: what the executed
    actions earned, a guider's included. Beside the deterministic evaluation it shows what
    the data in the buffer is worth; a curve point holds the mean over the episodes that
    ended since the point before (NaN when none did, or when some of them went unseen)."""

    def __init__(self, n: int = 1):
        self.running: np.ndarray = np.zeros(n)  # return so far of each episode in progress
        self.total: np.ndarray = np.zeros(n)  # of the episodes ended since the last take
        self.count: np.ndarray = np.zeros(n, dtype=np.int64)
        self.partial: np.ndarray = np.zeros(n, dtype=bool)  # some of those went unseen

    def add(self, rewards: np.ndarray | float, ended: np.ndarray | bool) -> None:
        """One env step of every env (rewards of idle envs are zero); ``ended``: which
        episodes ended with it. An episode whose start is unknown (NaN) is not counted."""
        self.running += rewards
        ended = np.broadcast_to(np.asarray(ended, dtype=bool), self.running.shape)
        counted = ended & np.isfinite(self.running)
        self.total[counted] += self.running[counted]
        self.count[counted] += 1
        self.running[ended] = 0.0

    def take(self) -> np.ndarray:
        """Each env's mean return since the last ``take``, and start counting afresh."""
        means = np.where(self.count > 0, self.total / np.maximum(self.count, 1), np.nan)
        means[self.partial] = np.nan
        self.total[:] = 0.0
        self.count[:] = 0
        self.partial[:] = False
        return means

    def state_dict(self) -> dict[str, np.ndarray]:
        return {
            "running": self.running.copy(),
            "total": self.total.copy(),
            "count": self.count.copy(),
            "partial": self.partial.copy(),
        }

    def load_state_dict(
        self, state: dict[str, np.ndarray] | None, between_episodes: bool = False
    ) -> None:
        """``None``: a checkpoint from before these were kept. The episodes that ended since
        the last point went unseen, so the next point has no value, and an episode in
        progress (unless the checkpoint was taken ``between_episodes``) is left out."""
        if state is None:
            self.running[:] = 0.0 if between_episodes else np.nan
            self.total[:] = 0.0
            self.count[:] = 0
            self.partial[:] = True
            return
        self.running[:] = state["running"]
        self.total[:] = state["total"]
        self.count[:] = state["count"]
        self.partial[:] = state["partial"]
