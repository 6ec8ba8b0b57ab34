import numpy as np
import pytest

from baselines.common.buffer import ReplayBuffer


def fill(buffer, n, start=0):
    for i in range(start, start + n):
        buffer.add(
            np.full(2, i, np.float32),
            np.full(1, -i, np.float32),
            float(i),
            np.full(2, i + 1, np.float32),
            terminated=(i % 3 == 0),
        )


def test_add_and_sample_keep_transitions_together():
    buffer = ReplayBuffer(obs_dim=2, act_dim=1, capacity=10)
    fill(buffer, 6)
    assert len(buffer) == 6
    batch = buffer.sample(64, np.random.default_rng(0))
    obs = batch.observations[:, 0].numpy()
    np.testing.assert_array_equal(batch.actions[:, 0].numpy(), -obs)
    np.testing.assert_array_equal(batch.rewards.numpy(), obs)
    np.testing.assert_array_equal(batch.next_observations[:, 0].numpy(), obs + 1)
    np.testing.assert_array_equal(batch.terminated.numpy(), (obs % 3 == 0).astype(np.float32))
    assert obs.max() <= 5


def test_ring_buffer_overwrites_oldest():
    buffer = ReplayBuffer(2, 1, capacity=4)
    fill(buffer, 6)
    assert len(buffer) == 4
    assert sorted(buffer.rewards.tolist()) == [2.0, 3.0, 4.0, 5.0]


def test_sampling_depends_only_on_the_generator():
    buffer = ReplayBuffer(2, 1, capacity=100)
    fill(buffer, 50)
    a = buffer.sample(8, np.random.default_rng(1)).rewards
    b = buffer.sample(8, np.random.default_rng(1)).rewards
    c = buffer.sample(8, np.random.default_rng(2)).rewards
    assert a.tolist() == b.tolist() and a.tolist() != c.tolist()


def test_state_dict_round_trip():
    buffer = ReplayBuffer(2, 1, capacity=8)
    fill(buffer, 5)
    copy = ReplayBuffer(2, 1, capacity=8)
    copy.load_state_dict(buffer.state_dict())
    assert len(copy) == 5 and copy.position == buffer.position
    np.testing.assert_array_equal(copy.observations, buffer.observations)


def test_bad_use_is_refused():
    with pytest.raises(ValueError):
        ReplayBuffer(2, 1, capacity=0)
    with pytest.raises(ValueError):
        ReplayBuffer(2, 1, capacity=3).sample(1, np.random.default_rng(0))
