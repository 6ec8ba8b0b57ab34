"""Replay buffer of transitions (s, a, r, s', terminated), shared by the off-policy algorithms."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class Batch:
    observations: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_observations: torch.Tensor
    terminated: torch.Tensor  # 1.0 only where the task ended; time-limit truncation is 0.0


class ReplayBuffer:
    """A ring buffer of fixed capacity in preallocated numpy arrays.

    Only ``terminated`` is stored as the done flag: a transition cut by a time limit keeps
    its real next state and is bootstrapped, as it should be.
    """

    def __init__(self, obs_dim: int, act_dim: int, capacity: int):
        if capacity <= 0:
            raise ValueError(f"replay capacity must be positive, got {capacity}")
        self.capacity = capacity
        self.observations = np.zeros((capacity, obs_dim), dtype=np.float32)
        self.actions = np.zeros((capacity, act_dim), dtype=np.float32)
        self.rewards = np.zeros(capacity, dtype=np.float32)
        self.next_observations = np.zeros((capacity, obs_dim), dtype=np.float32)
        self.terminated = np.zeros(capacity, dtype=np.float32)
        self.position = 0
        self.size = 0

    def __len__(self) -> int:
        return self.size

    def add(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
    ) -> None:
        i = self.position
        self.observations[i] = obs
        self.actions[i] = action
        self.rewards[i] = reward
        self.next_observations[i] = next_obs
        self.terminated[i] = float(terminated)
        self.position = self._slot_after(i)
        self.size = min(self.size + 1, self.capacity)

    def _slot_after(self, i: int) -> int:
        return (i + 1) % self.capacity

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """Uniform sample with replacement, drawn from ``rng`` only."""
        if self.size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        idx = rng.integers(0, self.size, size=batch_size)
        return Batch(
            observations=torch.from_numpy(self.observations[idx]),
            actions=torch.from_numpy(self.actions[idx]),
            rewards=torch.from_numpy(self.rewards[idx]),
            next_observations=torch.from_numpy(self.next_observations[idx]),
            terminated=torch.from_numpy(self.terminated[idx]),
        )

    ARRAYS: tuple[str, ...] = (
        "observations",
        "actions",
        "rewards",
        "next_observations",
        "terminated",
    )

    def state_dict(self) -> dict[str, np.ndarray | int]:
        n = self.size
        state: dict[str, np.ndarray | int] = {
            name: getattr(self, name)[:n].copy() for name in self.ARRAYS
        }
        state["position"] = self.position
        return state

    def load_state_dict(self, state: dict) -> None:
        n = len(state["rewards"])
        if n > self.capacity:
            raise ValueError(f"saved buffer holds {n} transitions, capacity is {self.capacity}")
        for name in self.ARRAYS:
            getattr(self, name)[:n] = state[name]
        self.size = n
        self.position = int(state["position"])
