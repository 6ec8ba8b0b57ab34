"""Checkpoints for resuming a run: one file, written atomically, read back whole.

A checkpoint is taken at an episode boundary, so the env's state is only its random
generator: restoring that generator and resetting gives the very start state the
uninterrupted run would have had. Together with the networks, optimisers, replay buffer and
every random stream, this makes a resumed run on CPU follow the same curve.
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from baselines.common.context import EvalPoint, TrainContext
from baselines.common.evaluation import evaluate


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


class TimeLimitReached(Exception):
    """A run stopped at its command's time limit, just after saving its checkpoint at
    ``step`` (None: it never started). Not an error of the run (so not a RuntimeError): the
    runner keeps the checkpoint, and the same command resumes from it."""

    def __init__(self, step: int | None):
        super().__init__(
            "not started: the time limit had passed"
            if step is None
            else f"stopped at the time limit after step {step}, checkpoint saved"
        )
        self.step = step

    def __reduce__(self):
        return self.__class__, (self.step,)  # crosses a process pool intact


def past(deadline: float | None) -> bool:
    """Whether the wall-clock ``deadline`` (``time.time()`` seconds; None: none) has passed."""
    return deadline is not None and time.time() >= deadline


def due(step: int, last_checkpoint_step: int, interval: int, deadline: float | None = None) -> bool:
    """Whether to checkpoint now: every ``interval`` env steps (0: never), and at the first
    chance after ``deadline``, whatever the interval, so that a run stopped there keeps its
    work."""
    return (interval > 0 and step - last_checkpoint_step >= interval) or past(deadline)


def stop_if_past(deadline: float | None, step: int) -> None:
    """Called just after a checkpoint: stop the run there once its deadline has passed."""
    if past(deadline):
        raise TimeLimitReached(step)


class OneRunCheckpoints:
    """A one-run trainer's evaluations and checkpoints (DDPGfD, PPO): the curve and both envs'
    random streams are saved with what the trainer adds, at the episode ends that are due,
    and a resumed run replays its curve to the context before it goes on."""

    def __init__(self, ctx: TrainContext, env: gym.Env, eval_env: gym.Env):
        self.ctx, self.env, self.eval_env = ctx, env, eval_env
        self.curve: list[EvalPoint] = []
        self.last_step = 0  # the step of the latest checkpoint (0: none yet)

    def evaluate(self, step: int, policy: Callable[[np.ndarray], np.ndarray]) -> None:
        returns = evaluate(self.eval_env, policy, self.ctx.eval_episodes)
        self._record(EvalPoint(step, tuple(returns)))

    def _record(self, point: EvalPoint) -> None:
        self.curve.append(point)
        self.ctx.on_eval(point)

    def resume(self) -> dict[str, Any] | None:
        """The saved state (the envs' streams restored, the curve replayed), or None."""
        state = load_checkpoint(self.ctx.checkpoint_path)
        if state is None:
            return None
        restore_env_rng(self.env, state["env_rng"])
        restore_env_rng(self.eval_env, state["eval_env_rng"])
        self.ctx.on_resume(state["step"])
        for point in state["curve"]:
            self._record(point)
        self.ctx.on_steps(state["step"])
        self.last_step = state["step"]
        return state

    def at_episode_end(self, step: int, trainer_state: Callable[[], dict[str, Any]]) -> None:
        """Checkpoint here if one is due (then stop if the deadline has passed)."""
        ctx = self.ctx
        if (
            ctx.checkpoint_path is None
            or step >= ctx.total_steps
            or not due(step, self.last_step, ctx.checkpoint_interval, ctx.deadline)
        ):
            return
        state = {
            "step": step,
            "curve": self.curve,
            "env_rng": env_rng_state(self.env),
            "eval_env_rng": env_rng_state(self.eval_env),
        }
        save_checkpoint(ctx.checkpoint_path, {**state, **trainer_state()})
        self.last_step = step
        stop_if_past(ctx.deadline, step)
