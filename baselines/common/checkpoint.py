"""Checkpoints for resuming a run: one file, written atomically, read back whole.

A checkpoint is taken at an episode boundary, so the env's state is only its random
generator: restoring that generator and resetting gives the very start state the
uninterrupted run would have had. Together with the networks, optimisers, replay buffer and
every random stream, this makes a resumed run on CPU follow the same curve.
"""

from __future__ import annotations

import copy
import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch


def env_rng_state(env: gym.Env) -> Any:
    """A copy of the env's random generator (numpy Generator or dm-control's RandomState)."""
    return copy.deepcopy(env.unwrapped.np_random)


def restore_env_rng(env: gym.Env, state: Any) -> None:
    env.unwrapped.np_random = copy.deepcopy(state)


class CheckpointDeviceError(Exception):
    """A checkpoint made on one kind of device met a run on another. Not a ValueError: the
    checkpoint is fine, and the harness must keep it."""


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    torch.save(state, tmp)
    os.replace(tmp, path)  # a kill during the write leaves the previous checkpoint intact


def load_checkpoint(path: Path | None) -> dict[str, Any] | None:
    """The checkpoint at ``path``, or None when there is none. Written by this harness only,
    so it is unpickled in full (it holds numpy and dm-control random states)."""
    if path is None or not Path(path).is_file():
        return None
    # on the CPU first: a checkpoint made on a GPU must open on a machine without one
    return torch.load(path, weights_only=False, map_location="cpu")


def due(step: int, last_checkpoint_step: int, interval: int) -> bool:
    return interval > 0 and step - last_checkpoint_step >= interval
