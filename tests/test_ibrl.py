import numpy as np
import pytest
import torch

from baselines.common.stacked import critic_pairs
from baselines.drl_eg import nearest_demo
from baselines.ibrl import IBRLAgent, IBRLConfig, ImitationPolicy
from replicate.demos import Demonstrations, default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR, curve_signature, train_tiny

SLOPE = 10.0
OBS, ACT = 2, 1  # MountainCar's
IL_ACTIONS = (1.0, -1.0)  # member 0's imitation proposes +1, member 1's -1


def q_linear_in_action(critics, obs_dim: int, slope: float) -> None:
    """Set every critic to Q(s, a) = slope * a (one action dimension, ReLU units kept on)."""
    with torch.no_grad():
        for w, b in zip(critics.weights, critics.biases):
            w.zero_()
            b.zero_()
        critics.weights[0][:, obs_dim, 0] = 1.0  # h = a + 2 > 0 on the action box [-1, 1]
        critics.biases[0][:, 0, 0] = 2.0
        critics.weights[1][:, 0, 0] = 1.0
        critics.weights[2][:, 0, 0] = slope
        critics.biases[2][:, 0, 0] = -2.0 * slope


class ConstantImitation:
    def __init__(self, value: float):
        self.value = value

    def __call__(self, states: np.ndarray) -> np.ndarray:
        return np.full((len(states), 1), self.value, dtype=np.float32)


def rigged_agent() -> IBRLAgent:
    """Two members whose target critics are Q = 10 a; member k's imitation proposes
    IL_ACTIONS[k] (per-member imitations are the BC kind's)."""
    config = IBRLConfig(hidden_sizes=(8, 8), imitation="bc")
    imitations = [ConstantImitation(a) for a in IL_ACTIONS]
    agent = IBRLAgent([0, 1], MOUNTAINCAR, config, imitations, demos=None)
    q_linear_in_action(agent.critics_target, obs_dim=OBS, slope=SLOPE)
    return agent


def test_rigged_critic_is_linear_in_the_action():
    agent = rigged_agent()
    actions = torch.tensor([[-1.0], [0.0], [0.5]]).expand(2, -1, -1)
    q = critic_pairs(agent.critics_target, torch.zeros(2, 3, OBS), actions)
    assert q.shape == (2, 2, 3)
    assert q.flatten(0, 1).tolist() == [pytest.approx([-SLOPE, 0.0, 0.5 * SLOPE])] * 4


def policy_mean(agent: IBRLAgent, obs: np.ndarray) -> np.ndarray:
    """Each member's actor's own deterministic action (no imitation)."""
    with torch.no_grad():
        return agent.policy.deterministic(torch.as_tensor(obs)[:, None])[:, 0].numpy()


def test_acting_executes_the_higher_valued_proposal():
    # Q = 10 a: member 0's imitation +1 beats any tanh-squashed sample, member 1's -1 loses
    agent = rigged_agent()
    obs = np.array([[0.3, -0.2], [-0.4, 0.1]], dtype=np.float32)
    states = [g.get_state() for g in agent.generators]
    with torch.no_grad():
        expected_rl, _ = agent.policy.sample(
            torch.as_tensor(obs)[:, None], noise=agent.member_noise(1)
        )
    for generator, state in zip(agent.generators, states):
        generator.set_state(state)
    action, used_il = agent.propose(obs, deterministic=False)
    assert used_il.tolist() == [True, False]
    assert action[0].tolist() == [IL_ACTIONS[0]]
    # member 1 executes its actor's proposal, with its exploration noise, not its mean
    assert action[1].tolist() == pytest.approx(expected_rl[1, 0].tolist(), abs=1e-7)
    assert action[1].tolist() != pytest.approx(policy_mean(agent, obs)[1].tolist())
    # acting is this choice; evaluation chooses between the same two, the actor's
    # proposal being its mean
    for generator, state in zip(agent.generators, states):
        generator.set_state(state)
    assert np.array_equal(agent.act(obs), action)
    deterministic, used_il = agent.propose(obs, deterministic=True)
    assert used_il.tolist() == [True, False]
    assert deterministic[0].tolist() == [IL_ACTIONS[0]]
    assert deterministic[1].tolist() == pytest.approx(policy_mean(agent, obs)[1].tolist())
    assert np.array_equal(agent.act_deterministic(obs), deterministic)


def test_target_bootstraps_from_the_higher_valued_proposal():
    agent = rigged_agent()
    next_obs = torch.randn(2, 6, OBS, generator=torch.Generator().manual_seed(1))
    noise = torch.randn(2, 6, ACT, generator=torch.Generator().manual_seed(2))
    alpha = torch.tensor([[0.3], [0.2]])
    il = torch.tensor(IL_ACTIONS)[:, None, None].expand(-1, 6, 1)
    value = agent.next_state_value(next_obs, noise, alpha, next_il_actions=il)
    with torch.no_grad():
        a_rl, log_prob = agent.policy.sample(next_obs, noise=noise)
    chosen = torch.stack([il[0, :, 0], a_rl[1, :, 0]])  # member 0 imitates, member 1 does not
    assert value.shape == (2, 6)
    assert value.tolist() == [
        pytest.approx(row, abs=1e-5) for row in (SLOPE * chosen - alpha * log_prob).tolist()
    ]

    # and the update feeds mu(s') of each sampled transition to it, member by member
    seen = {}

    def recorded(next_obs, next_noise, alpha, next_il_actions):
        seen["next_obs"], seen["il"] = next_obs.clone(), next_il_actions.clone()
        return next_state_value(next_obs, next_noise, alpha, next_il_actions=next_il_actions)

    next_state_value = agent.next_state_value
    agent.next_state_value = recorded
    agent.buffer = agent.make_replay(2, OBS, 20)
    rng = np.random.default_rng(0)
    for _ in range(10):
        obs = rng.normal(size=(2, OBS)).astype(np.float32)
        agent.buffer.add(obs, rng.uniform(-1, 1, (2, ACT)), rng.normal(size=2), -obs, np.zeros(2))
    agent.update([np.random.default_rng(s) for s in (0, 1)])
    rows = agent.config.batch_size
    assert seen["il"].shape == (2, rows, ACT)
    for k, value in enumerate(IL_ACTIONS):
        assert (seen["il"][k] == value).all()
    stored = {tuple(s) for s in agent.buffer.member(0).next_observations.tolist()}
    assert {tuple(s) for s in seen["next_obs"][0].tolist()} <= stored


def test_functional_imitation_is_the_nearest_demonstration_action_without_noise():
    rng = np.random.default_rng(0)
    demos = Demonstrations(
        rng.normal(size=(300, 3)).astype(np.float32),
        rng.uniform(-2, 2, (300, 2)).astype(np.float32),
        {"expert_return_mean": 1.0},
    )
    policy = ImitationPolicy(IBRLConfig(), demos, -np.ones(2), np.ones(2), seed=0)
    queries = rng.normal(size=(50, 3))
    actions = policy(queries)
    for query, action in zip(queries, actions):
        _, index = nearest_demo(demos.observations.astype(np.float64), query)
        assert action.tolist() == pytest.approx(np.clip(demos.actions[index], -1, 1).tolist())
    assert np.array_equal(policy(queries), actions)  # no noise


def test_ibrl_trains_deterministically_and_preloads_the_demonstrations():
    first, replay = train_tiny("ibrl", seed=3, steps=400)
    second, _ = train_tiny("ibrl", seed=3, steps=400)
    assert curve_signature(first) == curve_signature(second)
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    buffer = replay.member(0)
    assert replay.size == len(buffer.observations) == 1000 + 400
    assert np.array_equal(buffer.observations[:1000], demos.observations)
    assert np.array_equal(buffer.actions[:1000], demos.actions)
    # both proposals are executed: the untrained critics prefer one or the other
    assert 0.0 < first[1].guided_fraction < 1.0
    bc, bc_replay = train_tiny(
        "ibrl", seed=3, steps=200, imitation="bc", bc_steps=20, bc_hidden=(8,), preload_demos=False
    )
    assert len(bc) == 2 and np.isfinite(bc[-1].mean_return)
    assert bc_replay.size == 200  # nothing preloaded


def test_unknown_imitation_policy_is_refused():
    with pytest.raises(ValueError, match="imitation must be one of"):
        IBRLConfig(imitation="knn")
