import numpy as np
import pytest
import torch

from baselines.drl_eg import nearest_demo
from baselines.ibrl import IBRLAgent, IBRLConfig, ImitationPolicy
from replicate.demos import Demonstrations, default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR, curve_signature, train_tiny
from tests.test_resume import Killed, run

SLOPE = 10.0
HOPPER = "Hopper-v5"


def q_linear_in_action(critics, obs_dim: int, slope: float) -> None:
    """Set both critics to Q(s, a) = slope * a (one action dimension, ReLU units kept on)."""
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


def rigged_agent(il_action: float) -> IBRLAgent:
    config = IBRLConfig(hidden_sizes=(8, 8))
    agent = IBRLAgent(
        2, 1, -np.ones(1), np.ones(1), config, seed=0, imitation=ConstantImitation(il_action)
    )
    q_linear_in_action(agent.critics_target, obs_dim=2, slope=SLOPE)
    return agent


def test_rigged_critic_is_linear_in_the_action():
    agent = rigged_agent(1.0)
    q = agent.target_q(torch.zeros(3, 2), torch.tensor([[-1.0], [0.0], [0.5]]))
    assert q.tolist() == pytest.approx([-SLOPE, 0.0, 0.5 * SLOPE])


@pytest.mark.parametrize("il_action, imitation_wins", [(1.0, True), (-1.0, False)])
def test_acting_executes_the_higher_valued_proposal(il_action, imitation_wins):
    # Q = 10 a: the imitation's +1 beats any tanh-squashed sample, its -1 loses to any
    agent = rigged_agent(il_action)
    obs = np.array([0.3, -0.2], dtype=np.float32)
    state = agent.noise.get_state()
    with torch.no_grad():
        expected_rl, _ = agent.policy.sample(torch.as_tensor(obs)[None], agent.noise)
    agent.noise.set_state(state)
    action, used_il = agent.propose(obs)
    assert used_il == imitation_wins
    if imitation_wins:
        assert action.tolist() == [il_action]
    else:  # the actor's own proposal, with its exploration noise, not its mean
        assert action.tolist() == pytest.approx(expected_rl[0].tolist(), abs=1e-7)
        assert action.tolist() != pytest.approx(agent.act(obs, deterministic=True).tolist())
    # evaluation chooses between the same two, the actor's proposal being its mean
    deterministic, used_il = agent.propose(obs, deterministic=True)
    assert used_il == imitation_wins


@pytest.mark.parametrize("il_action, imitation_wins", [(1.0, True), (-1.0, False)])
def test_target_bootstraps_from_the_higher_valued_proposal(il_action, imitation_wins):
    agent = rigged_agent(il_action)
    next_obs = torch.randn(6, 2, generator=torch.Generator().manual_seed(1))
    noise = torch.randn(6, 1, generator=torch.Generator().manual_seed(2))
    alpha = torch.tensor(0.3)
    il = torch.full((6, 1), il_action)
    value = agent.next_state_value(next_obs, noise, alpha, next_il_actions=il)
    with torch.no_grad():
        a_rl, log_prob = agent.policy.sample(next_obs, noise=noise)
    chosen = torch.full((6,), il_action) if imitation_wins else a_rl[:, 0]
    assert value.tolist() == pytest.approx((SLOPE * chosen - alpha * log_prob).tolist(), abs=1e-5)
    # and the update feeds mu(s') of each sampled transition to it
    inputs = agent.target_inputs(type("B", (), {"next_observations": next_obs})())
    assert inputs["next_il_actions"].tolist() == il.tolist()


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
    first, buffer = train_tiny("ibrl", seed=3, steps=400)
    second, _ = train_tiny("ibrl", seed=3, steps=400)
    assert curve_signature(first) == curve_signature(second)
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    assert len(buffer) == 1000 + 400
    assert np.array_equal(buffer.observations[:1000], demos.observations)
    # both proposals are executed: the untrained critics prefer one or the other
    assert 0.0 < first[1].guided_fraction < 1.0
    bc, _ = train_tiny(
        "ibrl", seed=3, steps=200, imitation="bc", bc_steps=20, bc_hidden=(8,), preload_demos=False
    )
    assert len(bc) == 2 and np.isfinite(bc[-1].mean_return)


def test_unknown_imitation_policy_is_refused():
    with pytest.raises(ValueError, match="imitation must be one of"):
        IBRLConfig(imitation="knn")


def test_killed_ibrl_run_resumes_onto_the_uninterrupted_curve(tmp_path):
    # Hopper ends episodes quickly, which gives checkpoints before the kill
    overrides = {"hidden_sizes": (16, 16)}
    reference, reference_buffer, _ = run("ibrl", HOPPER, 600, **overrides)
    checkpoint = tmp_path / "checkpoint.pt"
    with pytest.raises(Killed):
        run("ibrl", HOPPER, 600, checkpoint_path=checkpoint, kill_at=450, **overrides)
    resumed, resumed_buffer, resumed_from = run(
        "ibrl", HOPPER, 600, checkpoint_path=checkpoint, **overrides
    )
    assert 150 < resumed_from < 450
    assert curve_signature(resumed) == curve_signature(reference)
    assert np.array_equal(
        resumed_buffer.actions[: len(reference_buffer)],
        reference_buffer.actions[: len(reference_buffer)],
    )
