"""What the runner hands an algorithm: the task, the budget, the demonstrations and the sinks."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np


class DemoSet(Protocol):
    """Demonstration pairs as an algorithm sees them (see ``replicate.demos``)."""

    observations: np.ndarray  # (n, obs_dim) float32
    actions: np.ndarray  # (n, act_dim) float32

    @property
    def mean_return(self) -> float: ...


@dataclass(frozen=True)
class EvalPoint:
    """One point of the evaluation curve."""

    step: int  # env steps taken so far
    returns: tuple[float, ...]  # return of each deterministic test episode
    guided_fraction: float = float("nan")  # share of steps since the last point taken by a guider
    gate_open: bool | None = None  # DRL-EG: was R_demo > R_pi after this evaluation
    # mean return of the training episodes (executed actions, guided or not) that ended
    # since the last point; NaN where none did or the loop does not record it
    train_return: float = float("nan")

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))


@dataclass
class TrainContext:
    env_id: str
    seed: int
    total_steps: int
    eval_interval: int
    eval_episodes: int
    demos: DemoSet | None = None
    device: str = "cpu"  # where an algorithm with a GPU path puts its tensors
    cuda_graphs: bool = True  # on CUDA, replay each gradient step as one captured graph
    on_eval: Callable[[EvalPoint], None] = field(default=lambda point: None)
    on_steps: Callable[[int], None] = field(default=lambda n: None)  # progress, in env steps
    # Resume: where the algorithm keeps its checkpoint, and how many env steps apart (at
    # the first episode end after each interval; 0 = never). An algorithm that finds a
    # checkpoint there resumes from it and re-emits the curve points it already had.
    on_resume: Callable[[int], None] = field(default=lambda step: None)  # step resumed from
    checkpoint_path: Path | None = None
    checkpoint_interval: int = 0
    # The command's time limit as a wall-clock time (time.time()); None: none. Once it has
    # passed, the run checkpoints at its next chance and stops (TimeLimitReached).
    deadline: float | None = None
    # Where to keep the weights of the policy with the best evaluation so far (experts).
    best_policy_path: Path | None = None
