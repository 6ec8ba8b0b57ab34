"""Small shared pieces of the tests."""

from __future__ import annotations

import contextlib
import dataclasses
import math

from baselines.common.context import EvalPoint, TrainContext
from baselines.registry import get_algorithm
from replicate.demos import default_demo_path, load_demos

TINY = {"hidden_sizes": (16, 16), "batch_size": 16, "learning_starts": 100}
MOUNTAINCAR = "MountainCarContinuous-v0"


def tiny_config(algo: str, **overrides):
    """``algo``'s config with the TINY settings it has, then ``overrides``."""
    algorithm = get_algorithm(algo)
    known = {f.name for f in dataclasses.fields(algorithm.config_cls)}
    tiny = {k: v for k, v in TINY.items() if k in known}  # each algorithm takes what it has
    return algorithm.make_config({**tiny, **overrides})


def train_tiny(algo: str, seed: int = 0, steps: int = 400, env_id: str = MOUNTAINCAR, **overrides):
    """Train ``algo`` briefly; return (curve, whatever ``train`` returns)."""
    algorithm = get_algorithm(algo)
    config = tiny_config(algo, **overrides)
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


@contextlib.contextmanager
def built_agents():
    """The SAC-family agents built inside the block, in order (the trainers keep theirs to
    themselves; the contract tests look at them once training is over)."""
    import pytest

    from baselines.offpolicy import OffPolicyAgent

    built: list = []
    ready = OffPolicyAgent._ready

    def recorded(agent, cuda_graphs: bool) -> None:
        built.append(agent)
        ready(agent, cuda_graphs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(OffPolicyAgent, "_ready", recorded)
        yield built


@dataclasses.dataclass
class TrainedBatch:
    curves: dict[int, list[EvalPoint]]  # by seed
    replay: object | None  # what the trainer returned; None when stopped
    agent: object  # the agent it built
    resumed_from: int | None  # the checkpoint's step, where it resumed from one


def train_batch(
    algo: str,
    config,
    path,
    stop_at: int | None = None,
    seeds=(0, 1),
    steps: int = 400,
    keep_best=None,
) -> TrainedBatch:
    """Train ``seeds`` of ``algo`` on MountainCar as one seed batch checkpointing into
    ``path`` every 100 steps (and, with ``keep_best``, keeping member k's best policy in
    ``keep_best / "best-<seed>.pt"``); with ``stop_at``, stop as if killed at that call of
    the progress callback."""
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
        TrainContext(
            MOUNTAINCAR,
            s,
            steps,
            200,
            1,
            demos=demos,
            on_eval=points[s].append,
            best_policy_path=None if keep_best is None else keep_best / f"best-{s}.pt",
        )
        for s in seeds
    ]
    resumed_from: list[int] = []
    bctx = BatchContext(
        contexts,
        on_steps=on_steps,
        on_resume=resumed_from.append,
        checkpoint_interval=100,
        checkpoint_path=path,
    )
    replay = None
    with built_agents() as built:
        try:
            replay = batched_trainer(algo)(bctx, [config] * len(seeds))
        except _Interrupted:
            pass
    return TrainedBatch(
        points, replay, built[-1] if built else None, resumed_from[0] if resumed_from else None
    )


def batch_curves(
    algo: str, config, path, stop_at: int | None = None, seeds=(0, 1), steps: int = 400
) -> dict[int, list[EvalPoint]]:
    """Each member's evaluation points, by seed, of ``train_batch``."""
    return train_batch(algo, config, path, stop_at, seeds, steps).curves


def fill_replays(batch, alone: list, capacity: int, steps: int = 60) -> None:
    """Give a seed batch of N and the batch of one of each of its seeds their replays, then
    the same ``steps`` random transitions: member k's are batch of one k's."""
    import numpy as np

    obs_dim = batch.policy.trunk.weights[0].shape[1]
    n, act_dim = batch.members, batch.act_dim
    batch.buffer = batch.make_replay(n, obs_dim, capacity)
    for agent in alone:
        agent.buffer = agent.make_replay(1, obs_dim, capacity)
    rng = np.random.default_rng(3)
    for _ in range(steps):
        rows = (
            rng.normal(size=(n, obs_dim)).astype(np.float32),
            rng.uniform(-1, 1, size=(n, act_dim)).astype(np.float32),
            rng.normal(size=n).astype(np.float32),
            rng.normal(size=(n, obs_dim)).astype(np.float32),
            (rng.random(n) < 0.1).astype(np.float32),
        )
        batch.buffer.add(*rows)
        for k, agent in enumerate(alone):
            agent.buffer.add(*(row[k : k + 1] for row in rows))


def assert_batch_updates_agree(batch, alone: list, seeds, updates: int) -> None:
    """``updates`` updates of a seed batch and of the batch of one of each of its seeds,
    member k and batch of one k drawing replay rows from a generator of seed k and noise
    from their own streams: the same losses, member by member, within 1e-5."""
    import numpy as np
    import pytest

    batch_rngs = [np.random.default_rng(s) for s in seeds]
    alone_rngs = [[np.random.default_rng(s)] for s in seeds]
    for _ in range(updates):
        losses = batch.update(batch_rngs)
        for k, agent in enumerate(alone):
            reference = agent.update(alone_rngs[k])
            assert set(losses) == set(reference)
            for name, value in reference.items():
                assert float(losses[name][k]) == pytest.approx(
                    float(value[0]), abs=1e-5, rel=1e-5
                ), name


def assert_members_agree(batch, alone: list, name: str, per_member: int = 1, atol=1e-5) -> None:
    """Member k's slices of the batch's stacked module ``name`` (``per_member`` stacked rows
    each: 2 for twin critics) equal the batch of one k's, within ``atol``; the
    temperatures too where the agents learn one."""
    import torch

    for k, agent in enumerate(alone):
        rows = slice(k * per_member, (k + 1) * per_member)
        mine, theirs = getattr(batch, name), getattr(agent, name)
        named = dict(theirs.named_parameters())
        assert len(named) == len(list(mine.parameters()))
        for param, value in mine.named_parameters():
            assert torch.allclose(value[rows], named[param], atol=atol), (name, param)
        for tensor in agent.TENSORS:  # a learned temperature, one per member
            assert torch.allclose(getattr(batch, tensor)[k], getattr(agent, tensor)[0], atol=atol)
