"""Small shared pieces of the tests."""

from __future__ import annotations

import dataclasses
import math

from baselines.common.context import EvalPoint, TrainContext
from baselines.registry import get_algorithm
from replicate.demos import default_demo_path, load_demos

TINY = {"hidden_sizes": (16, 16), "batch_size": 16, "learning_starts": 100}
MOUNTAINCAR = "MountainCarContinuous-v0"


def train_tiny(algo: str, seed: int = 0, steps: int = 400, env_id: str = MOUNTAINCAR,
               **overrides):
    """Train ``algo`` briefly; return (curve, whatever ``train`` returns)."""
    algorithm = get_algorithm(algo)
    known = {f.name for f in dataclasses.fields(algorithm.config_cls)}
    tiny = {k: v for k, v in TINY.items() if k in known}  # each algorithm takes what it has
    config = algorithm.make_config({**tiny, **overrides})
    points: list[EvalPoint] = []
    demos = load_demos(default_demo_path(env_id), env_id) if algorithm.needs_demos else None
    ctx = TrainContext(env_id=env_id, seed=seed, total_steps=steps, eval_interval=200,
                       eval_episodes=1, demos=demos, on_eval=points.append)
    buffer = algorithm.train(ctx, config)
    return points, buffer


def curve_signature(points: list[EvalPoint]) -> list[tuple]:
    """Comparable form of a curve; the step-0 guided fraction and training return are NaN
    and NaN != NaN."""
    def plain(value):
        return None if isinstance(value, float) and math.isnan(value) else value
    return [(p.step, tuple(p.returns), plain(p.guided_fraction), plain(p.train_return))
            for p in points]
