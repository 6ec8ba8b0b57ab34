import math

import numpy as np
import pytest
import torch
from torch import distributions as D

from baselines.common.networks import TanhGaussianPolicy, VNetwork, soft_update
from baselines.drl_eg import DRLEGConfig
from baselines.sac import SACAgent, SACConfig, q_target, v_target
from tests.helpers import MOUNTAINCAR, TINY, train_tiny


def test_q_target_hand_computed():
    # r = [1, 2], terminated = [0, 1], V'(s') = [10, 10], gamma = 0.99, scale = 5
    y = q_target(
        torch.tensor([1.0, 2.0]),
        torch.tensor([0.0, 1.0]),
        torch.tensor([10.0, 10.0]),
        gamma=0.99,
        reward_scale=5.0,
    )
    assert torch.allclose(y, torch.tensor([5.0 + 9.9, 10.0]))


def test_v_target_hand_computed():
    y = v_target(torch.tensor([3.0, -1.0]), torch.tensor([0.5, -2.0]))
    assert torch.allclose(y, torch.tensor([2.5, 1.0]))


def test_soft_update_is_polyak_average():
    torch.manual_seed(0)
    source, target = VNetwork(2, (4,)), VNetwork(2, (4,))
    before = [p.clone() for p in target.parameters()]
    soft_update(target, source, tau=0.25)
    for t, b, s in zip(target.parameters(), before, source.parameters()):
        assert torch.allclose(t, 0.75 * b + 0.25 * s)


def test_tanh_gaussian_log_prob_matches_torch_distributions():
    torch.manual_seed(0)
    low, high = np.array([-2.0, 0.0]), np.array([2.0, 1.0])
    policy = TanhGaussianPolicy(3, 2, low, high, hidden_sizes=(8,))
    obs = torch.randn(5, 3)
    action, log_prob = policy.sample(obs, torch.Generator().manual_seed(1))
    mean, log_std = policy(obs)
    scale = torch.tensor((high - low) / 2, dtype=torch.float32)
    bias = torch.tensor((high + low) / 2, dtype=torch.float32)
    reference = D.TransformedDistribution(
        D.Normal(mean, log_std.exp()),
        [D.TanhTransform(cache_size=1), D.AffineTransform(bias, scale)],
    )
    expected = reference.log_prob(action).sum(-1)
    assert torch.allclose(log_prob, expected, atol=1e-3)
    assert torch.all(action >= torch.tensor(low, dtype=torch.float32))
    assert torch.all(action <= torch.tensor(high, dtype=torch.float32))


def test_truncated_transitions_are_stored_as_not_terminated_with_their_real_next_state():
    # 1000 steps cross MountainCar's 999-step limit; no update happens (learning_starts > steps)
    _, replay = train_tiny("sac", steps=1000, learning_starts=5000)
    buffer = replay.member(0)
    assert buffer.terminated[:1000].sum() == 0.0
    last_of_episode = 998
    # the stored next state is the final state of the episode, not the reset state after it
    assert not np.array_equal(buffer.next_observations[last_of_episode], buffer.observations[999])
    np.testing.assert_array_equal(buffer.next_observations[997], buffer.observations[998])


def test_same_seed_same_curve_on_cpu():
    first, _ = train_tiny("sac", seed=3, steps=400)
    second, _ = train_tiny("sac", seed=3, steps=400)
    other, _ = train_tiny("sac", seed=4, steps=400)
    assert [p.returns for p in first] == [p.returns for p in second]
    assert [p.returns for p in first] != [p.returns for p in other]
    assert [p.step for p in first] == [0, 200, 400]


def test_sac_and_drl_eg_start_from_identical_weights():
    sac = SACAgent([11], MOUNTAINCAR, SACConfig(**TINY))
    drl = SACAgent([11], MOUNTAINCAR, DRLEGConfig(**TINY))
    for net in ("critics", "v", "v_target", "policy"):
        a, b = getattr(sac, net).state_dict(), getattr(drl, net).state_dict()
        assert all(torch.equal(a[k], b[k]) for k in a)
    other = SACAgent([12], MOUNTAINCAR, SACConfig(**TINY))
    assert not torch.equal(other.policy.trunk.weights[0], sac.policy.trunk.weights[0])


def test_update_reduces_q_loss_on_a_fixed_batch():
    agent = SACAgent([0], MOUNTAINCAR, SACConfig(hidden_sizes=(32, 32), learning_rate=1e-2))
    from baselines.common.buffer import Batch

    g = torch.Generator().manual_seed(0)
    batch = Batch(
        torch.randn(1, 64, 2, generator=g),
        torch.rand(1, 64, 1, generator=g) * 2 - 1,
        torch.randn(1, 64, generator=g),
        torch.randn(1, 64, 2, generator=g),
        torch.zeros(1, 64),
    )
    noise = torch.randn(1, 64, 1, generator=g)
    losses = [float(agent.gradient_step(batch, noise)["q_loss"][0]) for _ in range(60)]
    assert all(math.isfinite(x) for x in losses)
    assert losses[-1] < losses[0]


def test_training_returns_count_each_ended_episode_once_and_skip_unknown_starts():
    from baselines.common.evaluation import TrainingReturns

    returns = TrainingReturns(2)
    for rewards, ended in (
        ([1.0, 2.0], [False, False]),
        ([3.0, 4.0], [True, False]),
        ([5.0, 6.0], [True, True]),
    ):
        returns.add(np.array(rewards), np.array(ended))
    assert returns.take().tolist() == [4.5, 12.0]  # env 0: episodes of 4 and 5
    assert np.isnan(returns.take()).all()  # nothing ended since
    returns.add(np.array([1.0, 1.0]), np.array([False, False]))
    saved = returns.state_dict()
    resumed, unknown, between = TrainingReturns(2), TrainingReturns(2), TrainingReturns(2)
    resumed.load_state_dict(saved)
    unknown.load_state_dict(None)  # a checkpoint from before the returns were kept
    between.load_state_dict(None, between_episodes=True)  # ... taken at an episode's end
    for each in (resumed, unknown, between):
        each.add(np.array([2.0, 2.0]), np.array([True, False]))
    assert resumed.take()[0] == 3.0
    for each in (unknown, between):  # what ended before the resume went unseen
        assert np.isnan(each.take()).all()
        each.add(np.array([1.0, 1.0]), np.array([True, True]))
    after = unknown.take()
    assert after[0] == 1.0 and np.isnan(after[1])  # env 1's episode began before the resume
    assert between.take().tolist() == [1.0, 3.0]  # env 1's episode began after the resume


def test_the_curve_records_what_the_training_episodes_earned():
    """Each point's train_return is the mean return of the training episodes that ended
    since the point before, read back from the buffer's rewards (Hopper's untrained
    episodes end within a few dozen steps)."""
    points, replay = train_tiny("sac", steps=400, env_id="Hopper-v5")
    buffer = replay.member(0)
    rewards, ends = buffer.rewards[:400], np.flatnonzero(buffer.terminated[:400]) + 1
    expected, start = {200: [], 400: []}, 0
    for end in ends:
        expected[200 if end <= 200 else 400].append(float(rewards[start:end].sum()))
        start = end
    assert expected[200] and expected[400]
    assert math.isnan(points[0].train_return)
    for point in points[1:]:
        assert point.train_return == pytest.approx(np.mean(expected[point.step]), rel=1e-5)
