"""Kill a run after a checkpoint, start it again: it must finish on the uninterrupted curve."""

import dataclasses

import numpy as np
import pytest

from baselines.common.context import EvalPoint, TrainContext
from baselines.registry import get_algorithm
from envs import env_spec
from replicate.demos import default_demo_path, load_demos, rollout_demos
from tests.helpers import TINY, curve_signature


class Killed(Exception):
    pass


def zero_action_demos(env_id):
    """Stand-in demonstrations for an env without committed ones (Hopper ends episodes
    quickly, which gives checkpoints early)."""
    act_dim = env_spec(env_id).act_dim
    return rollout_demos(
        env_id,
        lambda obs: np.zeros(act_dim, np.float32),
        200,
        seed=0,
        command="test",
        description="zero actions",
    )


def run(algo, env_id, steps, checkpoint_path=None, kill_at=None, **overrides):
    algorithm = get_algorithm(algo)
    known = {f.name for f in dataclasses.fields(algorithm.config_cls)}
    config = algorithm.make_config({**{k: v for k, v in TINY.items() if k in known}, **overrides})
    demos = None
    if algorithm.needs_demos:
        path = default_demo_path(env_id)
        demos = load_demos(path, env_id) if path.is_file() else zero_action_demos(env_id)
    points: list[EvalPoint] = []
    done = 0
    first_report: list[int] = []

    def on_steps(n: int) -> None:
        nonlocal done
        done += n
        first_report[:] = first_report or [n]
        if kill_at is not None and done >= kill_at:
            raise Killed

    ctx = TrainContext(
        env_id=env_id,
        seed=7,
        total_steps=steps,
        eval_interval=150,
        eval_episodes=1,
        demos=demos,
        on_eval=points.append,
        on_steps=on_steps,
        checkpoint_path=checkpoint_path,
        checkpoint_interval=1,
    )
    buffer = algorithm.train(ctx, config)
    return points, buffer, first_report[0]


@pytest.mark.parametrize(
    "algo, env_id, overrides",
    [
        # the SAC family's trainers have theirs in the contract kit (tests/test_contract.py)
        ("ddpgfd", "Hopper-v5", {"hidden_sizes": (16, 16)}),  # short episodes: checkpoints
        # checkpoints fall inside a rollout of 256 steps: the partial rollout is saved too
        ("ppo", "Hopper-v5", {"rollout_steps": 256}),
        ("ppo-bc", "Hopper-v5", {"rollout_steps": 256, "bc_steps": 50}),
    ],
)
def test_killed_run_resumes_onto_the_uninterrupted_curve(tmp_path, algo, env_id, overrides):
    steps = 600
    reference, reference_buffer, _ = run(algo, env_id, steps, **overrides)
    checkpoint = tmp_path / "checkpoint.pt"
    with pytest.raises(Killed):
        run(algo, env_id, steps, checkpoint_path=checkpoint, kill_at=450, **overrides)
    assert checkpoint.is_file()
    resumed, resumed_buffer, resumed_from = run(
        algo, env_id, steps, checkpoint_path=checkpoint, **overrides
    )
    assert 150 < resumed_from < 450  # it did resume from a checkpoint, after some evaluations
    assert curve_signature(resumed) == curve_signature(reference)
    if reference_buffer is None:  # on-policy: nothing kept between rollouts
        return
    n = len(reference_buffer)
    assert np.array_equal(resumed_buffer.observations[:n], reference_buffer.observations[:n])
    assert np.array_equal(resumed_buffer.actions[:n], reference_buffer.actions[:n])
