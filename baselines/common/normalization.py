"""Running statistics for observation and reward normalisation (PPO's usual MuJoCo setting)."""

from __future__ import annotations

import numpy as np


class RunningMeanStd:
    """Mean and variance of a stream, merged batch by batch (parallel variance formula)."""

    def __init__(self, shape: tuple[int, ...] = (), epsilon: float = 1e-4):
        self.mean = np.zeros(shape, dtype=np.float64)
        self.var = np.ones(shape, dtype=np.float64)
        self.count = epsilon

    def update(self, batch: np.ndarray) -> None:
        batch = np.asarray(batch, dtype=np.float64).reshape(-1, *self.mean.shape)
        n = batch.shape[0]
        if n == 1:  # one env step: its mean is itself and its variance 0, exactly
            batch_mean, batch_var = batch[0], np.zeros_like(self.var)
        else:
            batch_mean, batch_var = batch.mean(axis=0), batch.var(axis=0)
        delta = batch_mean - self.mean
        total = self.count + n
        self.mean = self.mean + delta * n / total
        self.var = (
            self.var * self.count + batch_var * n + delta**2 * self.count * n / total
        ) / total
        self.count = total

    def normalize(self, x: np.ndarray, clip: float) -> np.ndarray:
        scaled = (np.asarray(x, dtype=np.float64) - self.mean) / np.sqrt(self.var + 1e-8)
        return np.clip(scaled, -clip, clip).astype(np.float32)


class ReturnScaler:
    """Divides rewards by the running std of the discounted return (as baselines' VecNormalize)."""

    def __init__(self, gamma: float, clip: float = 10.0):
        self.gamma, self.clip = gamma, clip
        self.stats = RunningMeanStd(())
        self.discounted = 0.0

    def __call__(self, reward: float, episode_over: bool) -> float:
        self.discounted = self.discounted * self.gamma + reward
        self.stats.update(np.array([self.discounted]))
        scaled = float(np.clip(reward / np.sqrt(self.stats.var + 1e-8), -self.clip, self.clip))
        if episode_over:
            self.discounted = 0.0
        return scaled
