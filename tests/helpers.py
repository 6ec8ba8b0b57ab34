"""Small shared pieces of the tests."""

from __future__ import annotations

import dataclasses
import math

from baselines.common.context import EvalPoint, TrainContext
from baselines.registry import get_algorithm
from replicate.demos import default_demo_path, load_demos

TINY = {"hidden_sizes": (16, 16), "batch_size": 16, "learning_starts": 100}
MOUNTAINCAR = "MountainCarContinuous-v0"


def train_tiny(algo: str, seed: int = 0, steps: int = 400, env_id: str = MOUNTAINCAR, **overrides):
    """Train ``algo`` briefly; return (curve, whatever ``train`` returns)."""
    algorithm = get_algorithm(algo)
    known = {f.name for f in dataclasses.fields(algorithm.config_cls)}
    tiny = {k: v for k, v in TINY.items() if k in known}  # each algorithm takes what it has
    config = algorithm.make_config({**tiny, **overrides})
    points: list[EvalPoint] = []
    demos = load_demos(default_demo_path(env_id), env_id) if algorithm.needs_demos else None
    ctx = TrainContext(
        env_id=env_id,
        seed=seed,
        total_steps=steps,
        eval_interval=200,
        eval_episodes=1,
        demos=demos,
        on_eval=points.append,
    )
    buffer = algorithm.train(ctx, config)
    return points, buffer


def curve_signature(points: list[EvalPoint]) -> list[tuple]:
    """Comparable form of a curve; the step-0 guided fraction and training return are NaN
    and NaN != NaN."""

    def plain(value):
        return None if isinstance(value, float) and math.isnan(value) else value

    return [
        (p.step, tuple(p.returns), plain(p.guided_fraction), plain(p.train_return)) for p in points
    ]


class _Interrupted(Exception):
    pass


def batch_curves(
    algo: str, config, path, stop_at: int | None = None, seeds=(0, 1), steps: int = 400
) -> dict[int, list[EvalPoint]]:
    """Train ``seeds`` of ``algo`` on MountainCar as one seed batch checkpointing into
    ``path`` every 100 steps; with ``stop_at``, stop as if killed at that call of the
    progress callback. Each member's evaluation points, by seed."""
    from baselines.common.context import BatchContext
    from baselines.registry import batched_trainer

    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    points: dict[int, list[EvalPoint]] = {s: [] for s in seeds}
    seen = [0]

    def on_steps(n: int) -> None:
        seen[0] += 1
        if stop_at is not None and seen[0] == stop_at:
            raise _Interrupted

    contexts = [
        TrainContext(MOUNTAINCAR, s, steps, 200, 1, demos=demos, on_eval=points[s].append)
        for s in seeds
    ]
    bctx = BatchContext(contexts, on_steps=on_steps, checkpoint_interval=100, checkpoint_path=path)
    try:
        batched_trainer(algo)(bctx, [config] * len(seeds))
    except _Interrupted:
        pass
    return points


def assert_batch_updates_agree(
    stacked, singles: list, buffers: list, rows: int, seeds, updates: int
) -> None:
    """``updates`` updates of a seed batch and of each member's one-run agent, each drawing
    its replay rows from a generator of its seed: the same losses, member by member, within
    1e-5."""
    import numpy as np
    import pytest

    stacked_rngs = [np.random.default_rng(s) for s in seeds]
    one_rngs = [np.random.default_rng(s) for s in seeds]
    for _ in range(updates):
        losses = stacked.update(stacked_rngs)
        for k, agent in enumerate(singles):
            reference = agent.update(buffers[k].sample(rows, one_rngs[k]))
            assert set(losses) == set(reference)
            for name, value in reference.items():
                assert float(losses[name][k]) == pytest.approx(float(value), abs=1e-5, rel=1e-5), (
                    name
                )


def assert_batch_policies_agree(stacked, singles: list) -> None:
    """Member k's stacked policy layers equal one-run agent k's, within 1e-5."""
    import torch

    for k, agent in enumerate(singles):
        linears = [m for m in agent.policy.trunk if isinstance(m, torch.nn.Linear)]
        for (weight, bias), layer in zip(stacked.policy.trunk.member_linear(k), linears):
            assert torch.allclose(weight, layer.weight, atol=1e-5)
            assert torch.allclose(bias, layer.bias, atol=1e-5)
