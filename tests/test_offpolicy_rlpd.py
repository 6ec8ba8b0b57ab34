"""RLPD on the off-policy trainer: member k of a batch samples, updates and trains as the
batch of one of its seed does, beside the others."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.ibrl import preloaded_buffer
from baselines.rlpd import RLPDAgent, RLPDConfig
from replicate.demos import default_demo_path, load_demos
from replicate.store.runner import execute_batch, prepare
from replicate.store.spec import RunSpec
from tests.helpers import (
    MOUNTAINCAR,
    TINY,
    assert_batch_updates_agree,
    assert_members_agree,
    fill_replays,
)

OBS, ACT, ROWS, SEEDS, CAPACITY = 2, 1, 32, (0, 1, 2), 200


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Agents updated here directly run on one thread, as training sets it (torch_threads)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _agents(**overrides):
    """A batch of 3 and the batch of one of each of its seeds, their replays holding the
    demonstrations and the same online transitions."""
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    config = RLPDConfig(hidden_sizes=(32, 32), batch_size=ROWS, **overrides)
    demo_buffer = preloaded_buffer(demos, OBS, ACT, online_capacity=0)

    def agent(seeds):
        return RLPDAgent(list(seeds), MOUNTAINCAR, config, demo_buffer, cuda_graphs=False)

    batch, alone = agent(SEEDS), [agent([s]) for s in SEEDS]
    fill_replays(batch, alone, CAPACITY)
    return demos, config, batch, alone


def test_a_members_symmetric_sample_is_that_of_its_seed_alone():
    """Member k's minibatch is the one its batch of one draws from a generator of its seed:
    half demonstration rows, first, then half its own online rows."""
    demos, _, batch, alone = _agents()
    sample = batch.buffer.sample(ROWS, [np.random.default_rng(s) for s in SEEDS])
    online = batch.buffer.split(batch.buffer.data[:, : batch.buffer.size])
    demo_obs = torch.from_numpy(np.asarray(demos.observations, dtype=np.float32))
    for k, (agent, seed) in enumerate(zip(alone, SEEDS)):
        one = agent.buffer.sample(ROWS, [np.random.default_rng(seed)])
        for name in ("observations", "actions", "rewards", "next_observations", "terminated"):
            assert torch.equal(getattr(sample, name)[k], getattr(one, name)[0]), name
        first, second = sample.observations[k, : ROWS // 2], sample.observations[k, ROWS // 2 :]
        assert all(bool((demo_obs == row).all(-1).any()) for row in first)
        assert all(bool((online.observations[k] == row).all(-1).any()) for row in second)


@pytest.mark.parametrize("utd", [1, 2])
def test_a_batched_rlpd_update_equals_each_members_update_alone(utd):
    """Six updates of a batch of 3 (its replay rows, noise and critic subsets drawn from
    each member's own streams) against the batches of one of its seeds: losses, then
    weights (the target critics' LayerNorm too) and temperatures, within 1e-5; with utd 2
    every other update is critic-only in both."""
    _, config, batch, alone = _agents(utd=utd)
    assert_batch_updates_agree(batch, alone, SEEDS, updates=6)
    assert batch.critic_updates == 6 and all(a.critic_updates == 6 for a in alone)
    assert_members_agree(batch, alone, "policy")
    for name in ("critics", "critics_target"):
        assert_members_agree(batch, alone, name, per_member=config.num_qs, atol=1e-6)


def _specs(seeds=(0, 1), steps: int = 400, **hyper):
    return [RunSpec("rlpd", MOUNTAINCAR, seed, steps, 200, 1, {**TINY, **hyper}) for seed in seeds]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("utd", [1, 2])  # 2: the critic-only steps' graph too
def test_a_batched_rlpd_trains_on_the_gpu_with_graphs(tmp_path, utd):
    members = [prepare(s) for s in _specs(seeds=(0, 1), steps=600, utd=utd)]
    outcome = execute_batch(members, tmp_path, device="cuda")
    assert not outcome.failed and len(outcome.runs) == 2
