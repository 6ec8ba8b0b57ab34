"""Prioritized replay (Schaul et al. 2016, arXiv:1511.05952) with a permanent demonstration region.

Slots ``[0, n_demo)`` hold demonstration transitions and are never overwritten, as DDPGfD
asks; agent transitions cycle through the rest. Sampling is proportional to p_i^alpha,
stratified over ``batch_size`` equal segments of the total, with a sum tree so that both
sampling and priority updates cost O(log capacity) per transition. Transitions are stored
in time order with an ``episode_end`` flag so that n-step returns can be read from the
buffer at sampling time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from baselines.common.buffer import ReplayBuffer


class SumTree:
    """Binary tree whose leaves are priorities and whose inner nodes hold the sums below them."""

    def __init__(self, capacity: int):
        self.leaves = 1
        while self.leaves < capacity:
            self.leaves *= 2
        self.nodes = np.zeros(2 * self.leaves, dtype=np.float64)  # node 1 is the root

    @property
    def total(self) -> float:
        return float(self.nodes[1])

    def update(self, indices: np.ndarray, values: np.ndarray) -> None:
        nodes = np.unique(np.asarray(indices) + self.leaves)
        # the last write of a repeated index wins, as with sequential assignment
        self.nodes[np.asarray(indices) + self.leaves] = values
        while nodes[0] > 1:
            nodes = np.unique(nodes // 2)
            self.nodes[nodes] = self.nodes[2 * nodes] + self.nodes[2 * nodes + 1]

    def get(self, indices: np.ndarray) -> np.ndarray:
        return self.nodes[np.asarray(indices) + self.leaves]

    def find(self, targets: np.ndarray) -> np.ndarray:
        """Leaf index i of each target t with prefix_sum(i) <= t < prefix_sum(i + 1)."""
        node = np.ones(len(targets), dtype=np.int64)
        targets = np.array(targets, dtype=np.float64)
        while node[0] < self.leaves:
            left = 2 * node
            go_right = targets >= self.nodes[left]
            targets = np.where(go_right, targets - self.nodes[left], targets)
            node = np.where(go_right, left + 1, left)
        return node - self.leaves


@dataclass
class PrioritizedBatch:
    indices: np.ndarray
    weights: torch.Tensor  # importance-sampling weights, max 1
    is_demo: np.ndarray
    observations: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_observations: torch.Tensor
    terminated: torch.Tensor
    n_step_returns: torch.Tensor  # sum_{k<m} gamma^k r_{t+k}, m <= n steps inside the episode
    n_step_next_observations: torch.Tensor  # s_{t+m}
    n_step_discounts: torch.Tensor  # gamma^m, or 0 where the episode terminated within m steps


class PrioritizedReplayBuffer(ReplayBuffer):
    """Transitions with priorities; demonstrations first and permanent."""

    ARRAYS = (*ReplayBuffer.ARRAYS, "episode_end")

    def __init__(self, obs_dim: int, act_dim: int, capacity: int, alpha: float):
        super().__init__(obs_dim, act_dim, capacity)
        self.alpha = alpha
        self.episode_end = np.zeros(capacity, dtype=bool)  # terminated or truncated
        self.tree = SumTree(capacity)
        self.max_priority = 1.0
        self.n_demo = 0  # self.position is the next agent slot

    def add_demonstrations(
        self,
        observations: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_observations: np.ndarray,
        terminated: np.ndarray,
        episode_end: np.ndarray,
    ) -> None:
        """Fill the permanent region; call once, before any agent transition."""
        n = len(observations)
        if n == 0:
            raise ValueError("no demonstrations to put in the replay buffer")
        if self.size or n >= self.capacity:
            raise ValueError("demonstrations go in first and must leave room for the agent")
        for name, values in (
            ("observations", observations),
            ("actions", actions),
            ("rewards", rewards),
            ("next_observations", next_observations),
            ("terminated", terminated),
            ("episode_end", episode_end),
        ):
            getattr(self, name)[:n] = values
        self.episode_end[n - 1] = True  # no demonstration follows the last one
        self.tree.update(np.arange(n), np.full(n, self.max_priority**self.alpha))
        self.n_demo = self.position = self.size = n

    def add(  # type: ignore[override]  # a truncation ends an n-step return too
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
        truncated: bool,
    ) -> None:
        self.episode_end[self.position] = terminated or truncated
        self.tree.update(np.array([self.position]), np.array([self.max_priority**self.alpha]))
        super().add(obs, action, reward, next_obs, terminated)

    def _slot_after(self, i: int) -> int:  # the demonstrations' slots are never overwritten
        return self.n_demo + (i + 1 - self.n_demo) % (self.capacity - self.n_demo)

    def state_dict(self) -> dict:
        state = super().state_dict()
        state.update(
            tree=self.tree.nodes.copy(), max_priority=self.max_priority, n_demo=self.n_demo
        )
        return state

    def load_state_dict(self, state: dict) -> None:
        if len(state["tree"]) != len(self.tree.nodes):
            raise ValueError("saved prioritized buffer does not fit this buffer's capacity")
        super().load_state_dict(state)
        self.tree.nodes[:] = state["tree"]
        self.max_priority, self.n_demo = state["max_priority"], state["n_demo"]

    def update_priorities(self, indices: np.ndarray, priorities: np.ndarray) -> None:
        """Set raw priorities p_i (already including the epsilons); stored as p_i^alpha."""
        self.max_priority = max(self.max_priority, float(np.max(priorities)))
        self.tree.update(indices, np.asarray(priorities, dtype=np.float64) ** self.alpha)

    def _newest(self) -> int:
        """Index of the most recent agent transition (its successor is not written yet)."""
        if self.size == self.n_demo:
            return -1
        return self.n_demo + (self.position - 1 - self.n_demo) % (self.capacity - self.n_demo)

    def _next_index(self, indices: np.ndarray) -> np.ndarray:
        demo = indices < self.n_demo
        agent_next = self.n_demo + (indices + 1 - self.n_demo) % max(self.capacity - self.n_demo, 1)
        return np.where(demo, indices + 1, agent_next)

    def n_step(
        self, indices: np.ndarray, n: int, gamma: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Discounted return of up to n steps from each index, the state reached, and the
        bootstrap discount; stops at an episode end or at the newest transition."""
        returns = np.zeros(len(indices), dtype=np.float64)
        discount = np.ones(len(indices), dtype=np.float64)
        last = indices.copy()
        current = indices.copy()
        active = np.ones(len(indices), dtype=bool)
        newest = self._newest()
        for _ in range(n):
            returns += np.where(active, discount * self.rewards[current], 0.0)
            discount = np.where(active, discount * gamma, discount)
            last = np.where(active, current, last)
            active &= ~self.episode_end[current] & (current != newest)
            current = np.where(active, self._next_index(current), current)
        discount *= 1.0 - self.terminated[last]
        return returns, self.next_observations[last], discount

    def sample(
        self, batch_size: int, beta: float, n: int, gamma: float, rng: np.random.Generator
    ) -> PrioritizedBatch:
        if self.size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        total = self.tree.total
        bounds = np.linspace(0.0, total, batch_size + 1)
        targets = rng.uniform(bounds[:-1], bounds[1:])
        indices = np.minimum(self.tree.find(targets), self.size - 1)
        probabilities = self.tree.get(indices) / total
        weights = (self.size * probabilities) ** (-beta)
        weights /= weights.max()
        returns, n_next, n_discount = self.n_step(indices, n, gamma)
        as_tensor = torch.from_numpy
        return PrioritizedBatch(
            indices=indices,
            weights=as_tensor(weights.astype(np.float32)),
            is_demo=indices < self.n_demo,
            observations=as_tensor(self.observations[indices]),
            actions=as_tensor(self.actions[indices]),
            rewards=as_tensor(self.rewards[indices]),
            next_observations=as_tensor(self.next_observations[indices]),
            terminated=as_tensor(self.terminated[indices]),
            n_step_returns=as_tensor(returns.astype(np.float32)),
            n_step_next_observations=as_tensor(n_next),
            n_step_discounts=as_tensor(n_discount.astype(np.float32)),
        )
