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


@dataclass
class BatchContext:
    """What the runner hands an off-policy trainer: one ``TrainContext`` per member (task,
    seed, budget, demonstrations, curve sink) and what the members share. A single run is a
    batch of one."""

    members: list[TrainContext]
    device: str = "cpu"
    cuda_graphs: bool = True
    env_workers: int = 0  # processes stepping the envs; 0: in this process
    on_steps: Callable[[int], None] = field(default=lambda n: None)  # env steps, all members
    on_resume: Callable[[int], None] = field(default=lambda step: None)
    on_member_failed: Callable[[int, str], None] = field(default=lambda k, reason: None)
    checkpoint_path: Path | None = None
    checkpoint_interval: int = 0
    deadline: float | None = None  # as TrainContext.deadline, for the batch as a whole

    @property
    def seeds(self) -> list[int]:
        return [m.seed for m in self.members]

    def shared(self, name: str) -> object:
        """A setting every member must have alike."""
        values = {getattr(m, name) for m in self.members}
        if len(values) != 1:
            raise ValueError(f"the members of a batch differ in {name}: {sorted(values)}")
        return values.pop()

    @classmethod
    def of_one(cls, ctx: TrainContext, on_failed: Callable[[int, str], None]) -> BatchContext:
        """The batch of one that trains ``ctx``'s run."""
        return cls(
            [ctx],
            device=ctx.device,
            cuda_graphs=ctx.cuda_graphs,
            on_steps=ctx.on_steps,
            on_resume=ctx.on_resume,
            on_member_failed=on_failed,
            checkpoint_path=ctx.checkpoint_path,
            checkpoint_interval=ctx.checkpoint_interval,
            deadline=ctx.deadline,
        )
