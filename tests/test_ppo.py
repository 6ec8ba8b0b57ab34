import numpy as np
import pytest
import torch

from baselines.common.context import TrainContext
from baselines.common.evaluation import evaluate
from baselines.common.normalization import RunningMeanStd
from baselines.ppo import build_agent, clipped_surrogate_loss, gae_advantages
from baselines.ppo_bc import PPOBCConfig, bc_loss, behaviour_clone
from envs import make_env
from replicate.demos import default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR, train_tiny

PPO_TINY = {"rollout_steps": 128, "minibatch_size": 32, "epochs": 2}


def test_gae_hand_computed_with_truncation_and_termination():
    # three steps: plain, truncated (bootstraps V(s'), chain cut), terminated (no bootstrap)
    rewards = np.array([1.0, 1.0, 1.0])
    values = np.array([0.5, 0.5, 0.5])
    next_values = np.array([0.5, 2.0, 9.0])
    terminated = np.array([0.0, 0.0, 1.0])
    over = np.array([0.0, 1.0, 1.0])
    gamma, lam = 0.9, 0.5
    adv = gae_advantages(rewards, values, next_values, terminated, over, gamma, lam)
    d2 = 1.0 - 0.5  # terminated: no V(s')
    d1 = 1.0 + 0.9 * 2.0 - 0.5  # truncated: bootstraps, but does not chain into step 2
    d0 = 1.0 + 0.9 * 0.5 - 0.5
    np.testing.assert_allclose(adv, [d0 + 0.9 * 0.5 * d1, d1, d2])


def test_clipped_surrogate_hand_computed():
    old = torch.log(torch.tensor([1.0, 1.0, 1.0]))
    new = torch.log(torch.tensor([1.5, 0.5, 1.1]))  # ratios 1.5, 0.5, 1.1
    adv = torch.tensor([1.0, -1.0, 2.0])
    # min(1.5*1, 1.2*1) = 1.2 ; min(0.5*-1, 0.8*-1) = -0.8 ; min(2.2, 2.2) = 2.2
    loss = clipped_surrogate_loss(new, old, adv, clip_coef=0.2)
    assert loss.item() == pytest.approx(-(1.2 - 0.8 + 2.2) / 3)


def test_bc_loss_hand_computed():
    predicted = torch.tensor([[0.5, 0.0], [0.0, 1.0]])
    demo = torch.tensor([[0.0, 0.0], [0.0, -1.0]])
    assert bc_loss(predicted, demo).item() == pytest.approx((0.25 + 4.0) / 2)


def test_running_mean_std_matches_numpy():
    data = np.random.default_rng(0).normal(3.0, 2.0, size=(1000, 2))
    stats = RunningMeanStd((2,))
    for chunk in np.array_split(data, 7):
        stats.update(chunk)
    np.testing.assert_allclose(stats.mean, data.mean(0), rtol=1e-4)
    np.testing.assert_allclose(stats.var, data.var(0), rtol=1e-3)


def test_behaviour_cloning_alone_learns_the_mountaincar_rule():
    ctx = TrainContext(env_id=MOUNTAINCAR, seed=0, total_steps=1, eval_interval=1, eval_episodes=1)
    config = PPOBCConfig(bc_steps=1500)
    agent = build_agent(ctx, config)
    before = evaluate(make_env(MOUNTAINCAR, seed=1), agent.act_deterministic, 2)
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    losses = behaviour_clone(agent, demos, config, seed=0)
    after = evaluate(make_env(MOUNTAINCAR, seed=1), agent.act_deterministic, 2)
    assert np.mean(losses[-100:]) < 0.25 * np.mean(losses[:10])
    assert max(before) < 50 and min(after) > 90


@pytest.mark.parametrize("algo", ["ppo", "ppo-bc"])
def test_same_seed_same_ppo_curve(algo):
    extra = {"bc_steps": 50} if algo == "ppo-bc" else {}
    first, _ = train_tiny(algo, seed=2, steps=400, **PPO_TINY, **extra)
    second, _ = train_tiny(algo, seed=2, steps=400, **PPO_TINY, **extra)
    assert [p.returns for p in first] == [p.returns for p in second]
    assert [p.step for p in first] == [0, 200, 400]


def test_fast_log_density_is_bitwise_torch_normal():
    from baselines.ppo import normal_log_prob

    g = torch.Generator().manual_seed(0)
    mean, value = torch.randn(7, 3, generator=g), torch.randn(7, 3, generator=g)
    std = torch.rand(3, generator=g).add(0.1).expand(7, 3)
    reference = torch.distributions.Normal(mean, std).log_prob(value)
    assert torch.equal(normal_log_prob(value, mean, std), reference)


def test_one_observation_statistics_update_is_bitwise_the_batch_formula():
    from baselines.common.normalization import RunningMeanStd

    rng = np.random.default_rng(0)
    fast, batch_path = RunningMeanStd((4,)), RunningMeanStd((4,))
    for _ in range(50):
        x = rng.normal(size=4) * 3 + 1
        fast.update(x)
        # the general path on a batch of one, as the code did before the shortcut
        b = x.reshape(1, 4)
        mean, var, n = b.mean(axis=0), b.var(axis=0), 1
        delta, total = mean - batch_path.mean, batch_path.count + n
        batch_path.mean = batch_path.mean + delta * n / total
        batch_path.var = (
            batch_path.var * batch_path.count + var * n + delta**2 * batch_path.count * n / total
        ) / total
        batch_path.count = total
    assert np.array_equal(fast.mean, batch_path.mean) and np.array_equal(fast.var, batch_path.var)
