"""The SAC authors' random start: uniform-random actions for the first steps of a run,
before the policy acts (1,000 steps on Hopper and Walker2d, 10,000 on HalfCheetah and Ant in
their code). Off by default: the harness starts with its initial policy."""

from __future__ import annotations

import numpy as np

_STREAM = 7  # keeps these draws apart from every other stream seeded from the run's seed


def random_start_action(seed: int, step: int, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Step ``step``'s uniform action of the run seeded ``seed``, from a stream of its own per
    step: a resumed run, and a seed batch's member, draw what the uninterrupted one-run
    draws, with no generator state to checkpoint."""
    rng = np.random.default_rng([seed, step, _STREAM])
    return rng.uniform(low, high).astype(np.float32)
