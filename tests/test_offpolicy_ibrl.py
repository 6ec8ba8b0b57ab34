"""Seed-batched IBRL: each member acts, bootstraps and trains as its one-run IBRL would."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.batched import StackedIBRLAgent, StackedTwinQAgent
from baselines.common.buffer import ReplayBuffer
from baselines.common.stacked import critic_pairs
from baselines.ibrl import IBRLAgent, IBRLConfig, ImitationPolicy, preloaded_buffer
from baselines.sac_twin_q import TwinQSACAgent
from replicate.demos import default_demo_path, load_demos
from replicate.runner import execute, execute_batch, prepare
from replicate.spec import RunSpec
from tests.helpers import (
    MOUNTAINCAR,
    TINY,
    assert_batch_policies_agree,
    assert_batch_updates_agree,
    batch_curves,
    curve_signature,
)

OBS, ACT, ROWS, SEEDS, CAPACITY = 2, 1, 32, (0, 1, 2), 200
LOW, HIGH = -np.ones(ACT, dtype=np.float32), np.ones(ACT, dtype=np.float32)


def _demos():
    return load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)


def _pair(imitation: str):
    """A batch of 3 and the one-run agents of its seeds, with their imitation policies."""
    demos = _demos()
    config = IBRLConfig(hidden_sizes=(32, 32), batch_size=ROWS, imitation=imitation, bc_steps=50)
    mus = [ImitationPolicy(config, demos, LOW, HIGH, s) for s in SEEDS]
    singles = [
        IBRLAgent(OBS, ACT, LOW, HIGH, config, s, mu, cuda_graphs=False)
        for s, mu in zip(SEEDS, mus)
    ]
    members = [TwinQSACAgent(OBS, ACT, LOW, HIGH, config, seed=s, cuda_graphs=False) for s in SEEDS]
    stacked = StackedIBRLAgent(
        members, config, mus[:1] if imitation == "functional" else mus, demos, "cpu"
    )
    return demos, config, stacked, singles


def _fill(stacked: StackedIBRLAgent, demos, steps: int = 60) -> list[ReplayBuffer]:
    """The stacked replay and each member's one-run replay, demonstrations first, then the
    same online transitions."""
    stacked.buffer = stacked.make_replay(len(SEEDS), OBS, CAPACITY)
    singles = [preloaded_buffer(demos, OBS, ACT, CAPACITY) for _ in SEEDS]
    rng = np.random.default_rng(3)
    for _ in range(steps):
        obs = rng.normal(size=(len(SEEDS), OBS)).astype(np.float32)
        act = rng.uniform(-1, 1, size=(len(SEEDS), ACT)).astype(np.float32)
        rew, nxt = rng.normal(size=len(SEEDS)), rng.normal(size=(len(SEEDS), OBS))
        term = rng.random(len(SEEDS)) < 0.1
        stacked.buffer.add(obs, act, rew, nxt, term)
        for k, buffer in enumerate(singles):
            buffer.add(obs[k], act[k], float(rew[k]), nxt[k], bool(term[k]))
    return singles


def test_each_members_replay_starts_with_the_demonstrations():
    demos, _, stacked, _ = _pair("functional")
    _fill(stacked, demos, steps=5)
    n = len(demos.observations)
    assert stacked.buffer.size == n + 5 and stacked.buffer.capacity == n + CAPACITY
    stored = stacked.buffer.split(stacked.buffer.data[:, :n])
    for k in range(len(SEEDS)):
        np.testing.assert_array_equal(
            stored.observations[k].numpy(), np.asarray(demos.observations, dtype=np.float32)
        )
        for name in ("actions", "rewards", "next_observations", "terminated"):
            np.testing.assert_array_equal(
                getattr(stored, name)[k].numpy(), np.asarray(getattr(demos, name), dtype=np.float32)
            )


@pytest.mark.parametrize("imitation", ["functional", "bc"])
def test_batched_ibrl_proposals_equal_one_run_proposals(imitation):
    """After a few updates, sampled and deterministic: the same executed actions, and the
    imitation policy wins where it wins in the one-run agent (whose choice is by its target
    critics), the actor's noise drawn from each member's one-run stream."""
    demos, _, stacked, singles = _pair(imitation)
    # trained first, so that the online and target critics differ as in training
    assert_batch_updates_agree(stacked, singles, _fill(stacked, demos), ROWS, SEEDS, updates=20)
    assert not torch.allclose(stacked.critics.weights[-1], stacked.critics_target.weights[-1])
    rng = np.random.default_rng(5)
    imitated_any = []
    for deterministic in (False, True, False):
        for _ in range(8):
            obs = rng.uniform([-1.2, -0.07], [0.6, 0.07], size=(len(SEEDS), OBS)).astype(np.float32)
            actions, imitated = stacked.propose(obs, deterministic)
            for k, agent in enumerate(singles):
                one_action, one_imitated = agent.propose(obs[k], deterministic)
                np.testing.assert_allclose(actions[k], one_action, atol=1e-5)
                assert bool(imitated[k]) == one_imitated
                imitated_any.append(one_imitated)
    assert any(imitated_any) and not all(imitated_any)  # both proposals win somewhere


def test_a_tie_between_the_proposals_goes_to_the_actor():
    """An imitation policy that proposes the actor's own deterministic action never counts
    as the winner (IBRL takes the imitation action only when its value is higher)."""
    _, _, stacked, _ = _pair("functional")
    stacked.imitation_actions = lambda states: stacked.policy.deterministic(
        torch.from_numpy(states.astype(np.float32))
    ).numpy()
    obs = np.random.default_rng(2).uniform([-1.2, -0.07], [0.6, 0.07], size=(len(SEEDS), OBS))
    _, imitated = stacked.propose(obs.astype(np.float32), deterministic=True)
    assert not imitated.any()


@pytest.mark.parametrize("imitation", ["functional", "bc"])
def test_batched_ibrl_updates_equal_one_run_updates(imitation):
    """Six updates of a batch of 3 (each member's rows and noise in its one-run order, its
    target bootstrapping from max(Q'(s', a'), Q'(s', mu(s')))) against the one-run agents:
    losses, then weights, within 1e-5."""
    demos, config, stacked, singles = _pair(imitation)
    buffers = _fill(stacked, demos)
    assert_batch_updates_agree(stacked, singles, buffers, ROWS, SEEDS, updates=6)
    assert_batch_policies_agree(stacked, singles)
    for k, agent in enumerate(singles):
        for mine, theirs in (
            (stacked.critics, agent.critics),
            (stacked.critics_target, agent.critics_target),
        ):
            for value, reference in zip(mine.parameters(), theirs.parameters()):
                assert torch.allclose(value[2 * k : 2 * k + 2], reference, atol=1e-5)
        assert torch.allclose(stacked.log_alpha[k], agent.log_alpha[0], atol=1e-6)


def test_the_target_bootstraps_from_the_higher_valued_proposal():
    """The defining term, per member: the next-state value is the larger of the actor's
    soft value and Q'(s', mu(s')) by that member's own target critics (alpha 0 here), and
    each of the two wins somewhere."""
    _, _, stacked, _ = _pair("functional")
    with torch.no_grad():  # members' target critics apart from their online ones
        for weight in stacked.critics_target.weights:
            weight.add_(0.3 * torch.randn_like(weight))
    rng = torch.Generator().manual_seed(0)
    next_obs = torch.randn((len(SEEDS), 16, OBS), generator=rng)
    noise = torch.randn((len(SEEDS), 16, ACT), generator=rng)
    il_actions = torch.rand((len(SEEDS), 16, ACT), generator=rng) * 2 - 1
    alpha = torch.zeros((len(SEEDS), 1))
    actor_value = StackedTwinQAgent.next_state_value(stacked, next_obs, noise, alpha)
    il_value = critic_pairs(stacked.critics_target, next_obs, il_actions).min(dim=1).values
    value = stacked.next_state_value(next_obs, noise, alpha, next_il_actions=il_actions)
    torch.testing.assert_close(value, torch.maximum(actor_value, il_value))
    assert bool((il_value > actor_value).any()) and bool((il_value < actor_value).any())


def _specs(seeds=(0, 1), steps: int = 400, **hyper):
    return [RunSpec("ibrl", MOUNTAINCAR, seed, steps, 200, 1, {**TINY, **hyper}) for seed in seeds]


def test_a_batched_ibrl_run_lands_on_its_one_run_curve(tmp_path):
    """Seed 1 trained in a batch beside seed 0 and alone: the same address and, on CPU,
    the same evaluation returns and guided fractions (to the printed digits). (The BC
    imitation's equality is the proposal and update tests'.)"""
    batch = execute_batch([prepare(s) for s in _specs()], tmp_path / "batch", device="cpu")
    alone = execute(prepare(_specs(seeds=(1,))[0]), tmp_path / "alone", device="cpu")
    assert not batch.failed and batch.runs[1].path.name == alone.path.name
    for column in ("return_mean", "guided_fraction"):
        np.testing.assert_allclose(
            batch.runs[1].curve[column], alone.curve[column], rtol=1e-4, atol=1e-3
        )
    assert batch.runs[0].curve["returns"].tolist() != batch.runs[1].curve["returns"].tolist()


def test_an_interrupted_ibrl_batch_resumes_onto_the_uninterrupted_curves(tmp_path):
    config = IBRLConfig(**TINY)
    whole = batch_curves("ibrl", config, tmp_path / "whole.pt")
    batch_curves("ibrl", config, tmp_path / "cut.pt", stop_at=250)
    resumed = batch_curves("ibrl", config, tmp_path / "cut.pt")
    for k in (0, 1):
        assert curve_signature(resumed[k]) == curve_signature(whole[k])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_batched_ibrl_trains_on_the_gpu(tmp_path):
    members = [prepare(s) for s in _specs(seeds=(0, 1), steps=600)]
    outcome = execute_batch(members, tmp_path, device="cuda")
    assert not outcome.failed and len(outcome.runs) == 2
