"""N envs of one id, one per member of a seed batch, stepped together.

Why not Gymnasium's vector envs: a batch must step only some of its envs (an evaluation
where one member has finished its episodes must not start another, or that member's env
stream would depend on its neighbours), and must restore an env in the middle of an
episode after ``kill -9``. Each env slot therefore remembers how its current episode began
(the random state before the reset, or the reset's seed) and the actions taken since; a
resumed batch resets from that state and replays the actions. MuJoCo and dm-control are
deterministic given those, so the env lands on the very state it had, and the caller checks
that it did.

The envs live in this process (``workers=0``, best when the updates dominate, as on a CPU)
or are split over worker processes that step their slices in parallel (a GPU machine, where
the GPU leaves the cores to the envs). Termination and truncation stay apart; an env that
ends an episode is reset in the same call when asked, and the caller gets both the final
observation (for the transition) and the first one of the next episode.
"""

from __future__ import annotations

import copy
import multiprocessing as mp
import traceback
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class StepResult:
    next_obs: np.ndarray  # (n, obs_dim): the observation the action led to (final if done)
    rewards: np.ndarray  # (n,) float64
    terminated: np.ndarray  # (n,) bool
    truncated: np.ndarray  # (n,) bool
    obs: np.ndarray  # (n, obs_dim): next_obs, or the reset observation where an env was reset


class _Slot:
    """One env and how its current episode began."""

    def __init__(self, env_id: str, seed: int):
        from envs import make_env

        self.env = make_env(env_id, seed=seed)
        self.obs_dim = self.env.observation_space.shape[0]
        self.episode_start: tuple[Any, int | None] | None = None  # (rng before reset, seed)
        self.actions: list[np.ndarray] = []

    def reset(self, seed: int | None) -> np.ndarray:
        self.episode_start = (copy.deepcopy(self.env.unwrapped.np_random), seed)
        self.actions = []
        obs, _ = self.env.reset(seed=seed)
        return obs

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        self.actions.append(np.array(action, dtype=np.float32))
        obs, reward, terminated, truncated, _ = self.env.step(action)
        return obs, reward, terminated, truncated

    def snapshot(self) -> dict[str, Any]:
        return {
            "rng": copy.deepcopy(self.env.unwrapped.np_random),
            "episode_start": copy.deepcopy(self.episode_start),
            "actions": [action.copy() for action in self.actions],
        }

    def restore(self, state: dict[str, Any]) -> np.ndarray | None:
        """Back to ``state``; the observation of the episode in progress, if one was."""
        if state["episode_start"] is None:
            self.env.unwrapped.np_random = copy.deepcopy(state["rng"])
            self.episode_start, self.actions = None, []
            return None
        rng, seed = state["episode_start"]
        self.env.unwrapped.np_random = copy.deepcopy(rng)
        obs = self.reset(seed)
        for action in state["actions"]:
            obs, *_ = self.step(action)
        return obs


class _Slice:
    """The envs one process owns; every method takes per-env arguments for its slice."""

    def __init__(self, env_id: str, seeds: list[int]):
        self.slots = [_Slot(env_id, seed) for seed in seeds]

    def reset(self, which: np.ndarray, seeds: list[int | None]) -> np.ndarray:
        dim = self.slots[0].obs_dim
        out = np.zeros((len(self.slots), dim), dtype=np.float32)
        for i, slot in enumerate(self.slots):
            if which[i]:
                out[i] = slot.reset(seeds[i])
        return out

    def step(
        self, actions: np.ndarray, active: np.ndarray, reset_done: np.ndarray
    ) -> tuple[np.ndarray, ...]:
        n, dim = len(self.slots), self.slots[0].obs_dim
        next_obs = np.zeros((n, dim), dtype=np.float32)
        obs = np.zeros((n, dim), dtype=np.float32)
        rewards = np.zeros(n)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        for i, slot in enumerate(self.slots):
            if not active[i]:
                continue
            next_obs[i], rewards[i], terminated[i], truncated[i] = slot.step(actions[i])
            obs[i] = next_obs[i]
            if reset_done[i] and (terminated[i] or truncated[i]):
                obs[i] = slot.reset(None)
        return next_obs, rewards, terminated, truncated, obs

    def snapshot(self) -> list[dict[str, Any]]:
        return [slot.snapshot() for slot in self.slots]

    def restore(self, states: list[dict[str, Any]]) -> list[np.ndarray | None]:
        return [slot.restore(state) for slot, state in zip(self.slots, states, strict=True)]


def _serve(conn: Any, env_id: str, seeds: list[int]) -> None:
    """A worker process: build its slice, then answer (method, args) messages until None."""
    try:
        envs = _Slice(env_id, seeds)
        conn.send(("ok", None))
    except Exception:  # the parent re-raises it with the worker's traceback
        conn.send(("error", traceback.format_exc()))
        return
    while True:
        try:
            message = conn.recv()
        except (EOFError, KeyboardInterrupt):  # the parent is gone or stopping: no traceback
            return
        if message is None:
            break
        method, args = message
        try:
            conn.send(("ok", getattr(envs, method)(*args)))
        except Exception:
            conn.send(("error", traceback.format_exc()))
    conn.close()


class EnvWorkerError(RuntimeError):
    pass


class EnvBatch:
    """``len(seeds)`` envs of ``env_id``, env k built as ``make_env(env_id, seed=seeds[k])``."""

    def __init__(self, env_id: str, seeds: list[int], workers: int = 0):
        self.n = len(seeds)
        if self.n < 1:
            raise ValueError("an env batch needs at least one env")
        workers = max(0, min(workers, self.n))
        bounds = np.linspace(0, self.n, workers + 1).round().astype(int) if workers else []
        self._ranges = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
        self._local: _Slice | None = None
        self._conns: list[Any] = []
        self._procs: list[Any] = []
        if not workers:
            self._local = _Slice(env_id, list(seeds))
        else:
            ctx = mp.get_context("spawn")  # no inherited torch or CUDA state in the workers
            for start, stop in self._ranges:
                parent, child = ctx.Pipe()
                proc = ctx.Process(
                    target=_serve, args=(child, env_id, list(seeds[start:stop])), daemon=True
                )
                proc.start()
                self._conns.append(parent)
                self._procs.append(proc)
            for conn in self._conns:
                self._receive(conn)
        probe = self._call("reset", [np.zeros(self.n, dtype=bool), [None] * self.n])
        self.obs_dim = probe.shape[1]

    @staticmethod
    def _receive(conn: Any) -> Any:
        status, value = conn.recv()
        if status == "error":
            raise EnvWorkerError(f"an env worker failed:\n{value}")
        return value

    def _call(self, method: str, per_env_args: list[Any]) -> Any:
        """Call ``method`` on every slice with its part of each per-env argument."""
        if self._local is not None:
            return getattr(self._local, method)(*per_env_args)
        for conn, (start, stop) in zip(self._conns, self._ranges):
            conn.send((method, [arg[start:stop] for arg in per_env_args]))
        parts = [self._receive(conn) for conn in self._conns]
        if isinstance(parts[0], tuple):
            return tuple(np.concatenate(column) for column in zip(*parts))
        if isinstance(parts[0], np.ndarray):
            return np.concatenate(parts)
        return [item for part in parts for item in part]

    def reset(
        self, which: np.ndarray | None = None, seeds: list[int | None] | None = None
    ) -> np.ndarray:
        """Reset the envs in ``which`` (default all), with ``seeds`` where given; rows of the
        others are zero."""
        which = np.ones(self.n, dtype=bool) if which is None else np.asarray(which, dtype=bool)
        return self._call("reset", [which, list(seeds) if seeds is not None else [None] * self.n])

    def step(
        self,
        actions: np.ndarray,
        active: np.ndarray | None = None,
        reset_done: np.ndarray | None = None,
    ) -> StepResult:
        """Step the ``active`` envs (default all); those in ``reset_done`` (default: the
        active ones) that end an episode are reset at once."""
        active = np.ones(self.n, dtype=bool) if active is None else np.asarray(active, dtype=bool)
        reset_done = active if reset_done is None else np.asarray(reset_done, dtype=bool)
        return StepResult(
            *self._call("step", [np.asarray(actions, dtype=np.float32), active, reset_done])
        )

    def snapshot(self) -> list[dict[str, Any]]:
        """Per env: its random state and how its current episode began (for a checkpoint)."""
        return self._call("snapshot", [])

    def restore(self, states: list[dict[str, Any]]) -> list[np.ndarray | None]:
        """Put every env back where ``snapshot`` found it; the observation of each episode
        in progress (None for an env between episodes)."""
        if len(states) != self.n:
            raise ValueError(f"{len(states)} env states for a batch of {self.n}")
        return self._call("restore", [states])

    def close(self) -> None:
        for conn in self._conns:
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for proc in self._procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()
        self._conns, self._procs = [], []
        if self._local is not None:
            for slot in self._local.slots:
                slot.env.close()

    def __enter__(self) -> EnvBatch:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
