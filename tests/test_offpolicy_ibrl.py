"""IBRL on the off-policy trainer: member k of a batch acts, bootstraps and trains as the
batch of one of its seed does, its replay starting with the demonstrations."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.common.stacked import critic_pairs
from baselines.ibrl import IBRLAgent, IBRLConfig, ImitationPolicy
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
LOW, HIGH = -np.ones(ACT, dtype=np.float32), np.ones(ACT, dtype=np.float32)


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Agents updated here directly run on one thread, as training sets it (torch_threads)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _demos():
    return load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)


def _agents(imitation: str):
    """A batch of 3 and the batch of one of each of its seeds, with their imitation
    policies as ``ibrl.train`` makes them (one functional policy serves every member; each
    seed fits its own BC net)."""
    demos = _demos()
    config = IBRLConfig(hidden_sizes=(32, 32), batch_size=ROWS, imitation=imitation, bc_steps=50)
    mus = [ImitationPolicy(config, demos, LOW, HIGH, s) for s in SEEDS]
    batch = IBRLAgent(
        list(SEEDS), MOUNTAINCAR, config, mus[:1] if imitation == "functional" else mus, demos
    )
    alone = [IBRLAgent([s], MOUNTAINCAR, config, [mu], demos) for s, mu in zip(SEEDS, mus)]
    return demos, batch, alone


def test_each_members_replay_starts_with_the_demonstrations():
    demos, batch, alone = _agents("functional")
    fill_replays(batch, alone, CAPACITY, steps=5)
    n = len(demos.observations)
    assert batch.buffer.size == n + 5 and batch.buffer.capacity == n + CAPACITY
    stored = batch.buffer.split(batch.buffer.data[:, :n])
    for k in range(len(SEEDS)):
        np.testing.assert_array_equal(
            stored.observations[k].numpy(), np.asarray(demos.observations, dtype=np.float32)
        )
        for name in ("actions", "rewards", "next_observations", "terminated"):
            np.testing.assert_array_equal(
                getattr(stored, name)[k].numpy(), np.asarray(getattr(demos, name), dtype=np.float32)
            )


@pytest.mark.parametrize("imitation", ["functional", "bc"])
def test_a_members_proposals_are_those_of_its_seed_alone(imitation):
    """After a few updates, sampled and deterministic: the same executed actions as the
    batches of one, and the imitation policy wins where it wins there (the choice by each
    member's target critics), the actor's noise drawn from each member's own stream."""
    _, batch, alone = _agents(imitation)
    fill_replays(batch, alone, CAPACITY)
    # trained first, so that the online and target critics differ as in training
    assert_batch_updates_agree(batch, alone, SEEDS, updates=20)
    assert not torch.allclose(batch.critics.weights[-1], batch.critics_target.weights[-1])
    rng = np.random.default_rng(5)
    imitated_any = []
    for deterministic in (False, True, False):
        for _ in range(8):
            obs = rng.uniform([-1.2, -0.07], [0.6, 0.07], size=(len(SEEDS), OBS)).astype(np.float32)
            actions, imitated = batch.propose(obs, deterministic)
            for k, agent in enumerate(alone):
                one_action, one_imitated = agent.propose(obs[k : k + 1], deterministic)
                np.testing.assert_allclose(actions[k], one_action[0], atol=1e-5)
                assert bool(imitated[k]) == bool(one_imitated[0])
                imitated_any.append(bool(one_imitated[0]))
    assert any(imitated_any) and not all(imitated_any)  # both proposals win somewhere


def test_a_tie_between_the_proposals_goes_to_the_actor():
    """An imitation policy that proposes the actor's own deterministic action never counts
    as the winner (IBRL takes the imitation action only when its value is higher)."""
    _, batch, _ = _agents("functional")
    batch.imitation_actions = lambda states: batch.policy.deterministic(
        torch.from_numpy(states.astype(np.float32))
    ).numpy()
    obs = np.random.default_rng(2).uniform([-1.2, -0.07], [0.6, 0.07], size=(len(SEEDS), OBS))
    _, imitated = batch.propose(obs.astype(np.float32), deterministic=True)
    assert not imitated.any()


@pytest.mark.parametrize("imitation", ["functional", "bc"])
def test_a_batched_ibrl_update_equals_each_members_update_alone(imitation):
    """Six updates of a batch of 3 (each member's replay rows and noise from its own
    streams, its target bootstrapping from max(Q'(s', a'), Q'(s', mu(s')))) against the
    batches of one of its seeds: losses, then weights and temperatures, within 1e-5."""
    _, batch, alone = _agents(imitation)
    fill_replays(batch, alone, CAPACITY)
    assert_batch_updates_agree(batch, alone, SEEDS, updates=6)
    for name, per_member in (("policy", 1), ("critics", 2), ("critics_target", 2)):
        assert_members_agree(batch, alone, name, per_member)


def test_the_target_bootstraps_from_the_higher_valued_proposal():
    """The defining term, per member: the next-state value is the larger of the actor's
    soft value and Q'(s', mu(s')) by that member's own target critics (alpha 0 here), and
    each of the two wins somewhere."""
    _, batch, _ = _agents("functional")
    with torch.no_grad():  # members' target critics apart from their online ones
        for weight in batch.critics_target.weights:
            weight.add_(0.3 * torch.randn_like(weight))
    rng = torch.Generator().manual_seed(0)
    next_obs = torch.randn((len(SEEDS), 16, OBS), generator=rng)
    noise = torch.randn((len(SEEDS), 16, ACT), generator=rng)
    il_actions = torch.rand((len(SEEDS), 16, ACT), generator=rng) * 2 - 1
    alpha = torch.zeros((len(SEEDS), 1))
    with torch.no_grad():
        actions, log_prob = batch.policy.sample(next_obs, noise=noise)
        actor_value = critic_pairs(batch.critics_target, next_obs, actions).min(dim=1).values
    actor_value = actor_value - alpha * log_prob
    il_value = critic_pairs(batch.critics_target, next_obs, il_actions).min(dim=1).values
    value = batch.next_state_value(next_obs, noise, alpha, next_il_actions=il_actions)
    torch.testing.assert_close(value, torch.maximum(actor_value, il_value))
    assert bool((il_value > actor_value).any()) and bool((il_value < actor_value).any())


def _specs(seeds=(0, 1), steps: int = 400, **hyper):
    return [RunSpec("ibrl", MOUNTAINCAR, seed, steps, 200, 1, {**TINY, **hyper}) for seed in seeds]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_batched_ibrl_trains_on_the_gpu(tmp_path):
    members = [prepare(s) for s in _specs(seeds=(0, 1), steps=600)]
    outcome = execute_batch(members, tmp_path, device="cuda")
    assert not outcome.failed and len(outcome.runs) == 2
