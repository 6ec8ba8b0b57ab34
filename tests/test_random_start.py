"""The SAC authors' random start as a setting of the SAC family: off by default and then out
of a run's address (every committed run still resolves to its directory), and when on, the
first steps' actions are the seed's own uniform draws, in one run and in a seed batch."""

import json
from pathlib import Path

import numpy as np
import pytest

from baselines.common.random_start import random_start_action
from replicate.runner import prepare
from replicate.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY, batch_curves, train_tiny

ROOT = Path(__file__).resolve().parents[1]


def _committed_by_algo() -> list[Path]:
    """One committed run of each algorithm and env (resolving loads its demonstrations)."""
    seen, runs = set(), []
    for spec_file in sorted((ROOT / "runs").glob("[!.]*/spec.json")):
        algo, env = spec_file.parent.name.split("__")[:2]
        if (algo, env) not in seen:
            seen.add((algo, env))
            runs.append(spec_file.parent)
    return runs


@pytest.mark.parametrize("run_dir", _committed_by_algo(), ids=lambda p: p.name)
def test_committed_runs_keep_their_addresses(run_dir):
    resolved = json.loads((run_dir / "spec.json").read_text())
    assert "random_start_steps" not in resolved["hyperparameters"]
    spec = RunSpec(
        resolved["algo"],
        resolved["env_id"],
        resolved["seed"],
        resolved["total_steps"],
        resolved["eval_interval"],
        resolved["eval_episodes"],
        resolved["hyperparameters"],
        resolved.get("demos_path"),
    )
    assert prepare(spec).run_id == run_dir.name


def test_a_random_start_changes_the_address_and_is_recorded():
    plain = prepare(RunSpec("sac", MOUNTAINCAR, 0, 400, 200, 1, dict(TINY)))
    random = prepare(
        RunSpec("sac", MOUNTAINCAR, 0, 400, 200, 1, dict(TINY, random_start_steps=150))
    )
    assert plain.run_id != random.run_id
    assert random.resolved["hyperparameters"]["random_start_steps"] == 150


def test_one_run_takes_its_seeds_uniform_actions_first():
    _, buffer = train_tiny("sac", seed=3, steps=300, random_start_steps=150)
    low, high = np.array([-1.0]), np.array([1.0])
    expected = np.stack([random_start_action(3, step, low, high) for step in range(1, 151)])
    np.testing.assert_array_equal(buffer.actions[:150], expected)
    assert not np.array_equal(
        buffer.actions[150:300],
        np.stack([random_start_action(3, step, low, high) for step in range(151, 301)]),
    )


def test_a_seed_batch_member_draws_its_one_run_random_start(tmp_path, monkeypatch):
    """Each member's first actions are the draws its one-run would take (the same function
    of its own seed and the step), and the policy acts from the step after."""
    import baselines.batched as batched
    from baselines.registry import get_algorithm

    drawn = []

    def recording(seed, step, low, high):
        drawn.append((seed, step))
        return random_start_action(seed, step, low, high)

    monkeypatch.setattr(batched, "random_start_action", recording)
    config = get_algorithm("sac").make_config(dict(TINY, random_start_steps=150))
    batch_curves("sac", config, tmp_path / "batch", seeds=(0, 1), steps=400)
    assert drawn == [(seed, step) for step in range(1, 151) for seed in (0, 1)]
