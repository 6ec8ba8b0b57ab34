import numpy as np
import pytest
import torch

from baselines.common.prioritized import PrioritizedReplayBuffer, SumTree
from baselines.ddpgfd import DDPGfDAgent, DDPGfDConfig, n_step_target, transition_priorities
from tests.helpers import curve_signature, train_tiny

GAMMA = 0.5


def test_sum_tree_sums_and_finds_by_prefix():
    tree = SumTree(5)
    tree.update(np.arange(5), np.array([1.0, 2.0, 0.5, 0.5, 4.0]))
    assert tree.total == pytest.approx(8.0)
    # prefix sums: [0,1) -> 0, [1,3) -> 1, [3,3.5) -> 2, [3.5,4) -> 3, [4,8) -> 4
    found = tree.find(np.array([0.0, 0.99, 1.0, 2.9, 3.2, 3.7, 4.0, 7.99]))
    assert found.tolist() == [0, 0, 1, 1, 2, 3, 4, 4]
    tree.update(np.array([4, 4]), np.array([9.0, 1.0]))  # the last write wins
    assert tree.total == pytest.approx(5.0) and tree.get(np.array([4]))[0] == 1.0


def filled_buffer(capacity: int = 8) -> PrioritizedReplayBuffer:
    """Two demo transitions (one episode, cut), then agent steps with rewards 1, 2, 3, ..."""
    buffer = PrioritizedReplayBuffer(obs_dim=1, act_dim=1, capacity=capacity, alpha=1.0)
    buffer.add_demonstrations(
        observations=np.array([[10.0], [11.0]]),
        actions=np.zeros((2, 1)),
        rewards=np.array([10.0, 20.0]),
        next_observations=np.array([[11.0], [12.0]]),
        terminated=np.zeros(2),
        episode_end=np.zeros(2, dtype=bool),
    )
    return buffer


def add_steps(buffer, rewards, terminated_at=None, truncated_at=None):
    for t, r in enumerate(rewards):
        buffer.add(
            np.array([float(t)]),
            np.zeros(1),
            r,
            np.array([t + 1.0]),
            terminated=t == terminated_at,
            truncated=t == truncated_at,
        )


def test_n_step_return_hand_computed_stops_at_termination():
    buffer = filled_buffer()
    add_steps(buffer, [1.0, 2.0, 3.0, 4.0], terminated_at=2)
    returns, next_obs, discount = buffer.n_step(np.array([2, 3, 4]), n=3, gamma=GAMMA)
    # from slot 2 (r=1): 1 + .5*2 + .25*3, terminated after the third step -> no bootstrap
    assert returns[0] == pytest.approx(1 + 0.5 * 2 + 0.25 * 3) and discount[0] == 0.0
    # from slot 3 (r=2): 2 + .5*3, episode ended at slot 4
    assert returns[1] == pytest.approx(2 + 0.5 * 3) and discount[1] == 0.0
    # slot 5 begins a new episode and is the newest: one step, bootstrapped with gamma
    returns, next_obs, discount = buffer.n_step(np.array([5]), n=3, gamma=GAMMA)
    assert returns[0] == 4.0 and discount[0] == GAMMA and next_obs[0, 0] == 4.0


def test_n_step_bootstraps_through_truncation_and_stops_at_the_demo_boundary():
    buffer = filled_buffer()
    add_steps(buffer, [1.0, 2.0, 3.0], truncated_at=1)
    returns, next_obs, discount = buffer.n_step(np.array([2]), n=3, gamma=GAMMA)
    assert returns[0] == pytest.approx(1 + 0.5 * 2)
    assert discount[0] == pytest.approx(GAMMA**2) and next_obs[0, 0] == 2.0
    # the last demonstration has no successor: 20, bootstrapped from its next state
    returns, next_obs, discount = buffer.n_step(np.array([0, 1]), n=3, gamma=GAMMA)
    assert returns.tolist() == [10 + 0.5 * 20, 20.0]
    assert discount.tolist() == [GAMMA**2, GAMMA] and next_obs[:, 0].tolist() == [12.0, 12.0]


def test_demonstrations_are_never_overwritten():
    buffer = filled_buffer(capacity=5)
    add_steps(buffer, [float(r) for r in range(10)])
    assert buffer.observations[:2, 0].tolist() == [10.0, 11.0]
    assert sorted(buffer.rewards[2:].tolist()) == [7.0, 8.0, 9.0]  # the newest agent steps


def test_sampling_follows_priorities_and_weights_correct_for_them():
    buffer = filled_buffer(capacity=4)
    add_steps(buffer, [0.0, 0.0])
    buffer.update_priorities(np.arange(4), np.array([1.0, 1.0, 1.0, 5.0]))
    batch = buffer.sample(8000, beta=1.0, n=1, gamma=GAMMA, rng=np.random.default_rng(0))
    share = np.mean(batch.indices == 3)
    assert share == pytest.approx(5 / 8, abs=0.02)
    weights = dict(zip(batch.indices.tolist(), batch.weights.tolist(), strict=True))
    assert weights[3] == pytest.approx(1 / 5) and weights[0] == 1.0  # (N P)^-1, max-normalised


def test_priority_formula_hand_computed():
    config = DDPGfDConfig(lambda_actor_priority=2.0, priority_eps=0.01, priority_eps_demo=1.0)
    priorities = transition_priorities(
        np.array([0.5, -1.0]), np.array([[3.0, 4.0], [0.0, 0.0]]), np.array([True, False]), config
    )
    assert priorities.tolist() == pytest.approx([0.25 + 2 * 25 + 0.01 + 1.0, 1.0 + 0.01])


def test_n_step_target_hand_computed():
    target = n_step_target(
        torch.tensor([1.75, 4.0]), torch.tensor([0.0, 0.5]), torch.tensor([100.0, 10.0])
    )
    assert target.tolist() == [1.75, 9.0]


def test_update_reduces_critic_loss_on_a_fixed_batch():
    buffer = filled_buffer(capacity=64)
    rng = np.random.default_rng(0)
    for _ in range(40):
        buffer.add(
            rng.normal(size=1),
            rng.uniform(-1, 1, 1),
            rng.normal(),
            rng.normal(size=1),
            terminated=False,
            truncated=False,
        )
    agent = DDPGfDAgent(
        1,
        1,
        np.array([-1.0]),
        np.array([1.0]),
        DDPGfDConfig(hidden_sizes=(32, 32), critic_learning_rate=1e-2),
        seed=0,
    )
    batch = buffer.sample(32, beta=1.0, n=3, gamma=0.9, rng=rng)
    first, priorities = agent.update(batch)
    for _ in range(100):
        last, _ = agent.update(batch)
    assert last["critic_loss"] < 0.5 * first["critic_loss"]
    assert priorities.shape == (32,) and (priorities > 0).all()


def test_ddpgfd_is_deterministic_and_explains_missing_transitions(monkeypatch):
    first, buffer = train_tiny("ddpgfd", seed=4, steps=300, hidden_sizes=(16, 16))
    second, _ = train_tiny("ddpgfd", seed=4, steps=300, hidden_sizes=(16, 16))
    assert curve_signature(first) == curve_signature(second)
    assert buffer.n_demo == 1000 and len(buffer) == 1300

    from replicate import demos as demos_module

    original = demos_module.load_demos

    def pairs_only(path, env_id):
        loaded = original(path, env_id)
        loaded.rewards = None
        return loaded

    monkeypatch.setattr("tests.helpers.load_demos", pairs_only)
    with pytest.raises(ValueError, match="needs demonstration transitions"):
        train_tiny("ddpgfd", seed=4, steps=10)


def test_denormals_are_flushed_while_ddpgfd_trains_and_not_after():
    from baselines.common.device import flush_denormals

    tiny = torch.tensor([1e-39], dtype=torch.float32)  # a denormal float32
    assert (tiny * 1.0).item() != 0.0
    with flush_denormals(True):
        assert (tiny * 1.0).item() == 0.0
    with flush_denormals(False):
        assert (tiny * 1.0).item() != 0.0
    assert DDPGfDConfig().flush_denormals
    train_tiny("ddpgfd", seed=4, steps=50, hidden_sizes=(16, 16))
    assert (tiny * 1.0).item() != 0.0  # the next run in this process computes as before


def test_every_registered_trainer_runs_with_denormals_flushed():
    from baselines import registry
    from baselines.sac import SACConfig

    seen = []

    def probe(*args):
        seen.append((torch.tensor([1e-39]) * 1.0).item())

    registry.register("probe-denormals", SACConfig)(probe)
    try:
        registry.get_algorithm("probe-denormals").train(None, None)
    finally:
        registry._REGISTRY.pop("probe-denormals")
    registry.register("probe-denormals", SACConfig, batchable=True)(probe)
    try:
        registry.batched_trainer("probe-denormals")(None, None)
    finally:
        registry._REGISTRY.pop("probe-denormals")
    assert seen == [0.0, 0.0]
    assert (torch.tensor([1e-39]) * 1.0).item() != 0.0  # and not after
