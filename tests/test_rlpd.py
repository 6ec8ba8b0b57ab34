import numpy as np
import pytest
import torch
from torch.nn import functional as F

from baselines.common.buffer import Batch
from baselines.rlpd import LayerNormCriticEnsemble, RLPDAgent, RLPDConfig, SymmetricReplay
from replicate.demos import Demonstrations, default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR, curve_signature, train_tiny
from tests.test_resume import Killed, run


def marked_demos(n: int = 30) -> Demonstrations:
    """Demonstration transitions with reward 1 and states 100 + i; online ones get reward 0."""
    obs = (100.0 + np.arange(n, dtype=np.float32))[:, None].repeat(2, 1)
    return Demonstrations(
        obs,
        np.zeros((n, 1), np.float32),
        {"expert_return_mean": 1.0},
        rewards=np.ones(n, np.float32),
        next_observations=obs + 1,
        terminated=np.zeros(n, np.float32),
        truncated=np.zeros(n, np.float32),
    )


def test_every_sample_is_exactly_half_demonstrations():
    replay = SymmetricReplay(marked_demos(), obs_dim=2, act_dim=1, capacity=50)
    for t in range(7):
        replay.add(np.full(2, float(t)), np.zeros(1), 0.0, np.full(2, t + 1.0), False)
    rng = np.random.default_rng(0)
    for batch_size in (2, 16, 64):
        batch = replay.sample(batch_size, rng)
        half = batch_size // 2
        assert len(batch.rewards) == batch_size
        assert batch.rewards[:half].tolist() == [1.0] * half  # demonstrations first
        assert batch.rewards[half:].tolist() == [0.0] * half
        assert (batch.observations[:half] >= 100).all() and (batch.observations[half:] < 7).all()
    with pytest.raises(ValueError, match="must be even"):
        RLPDConfig(batch_size=15)


def test_layer_norm_ensemble_is_independent_normalised_mlps():
    torch.manual_seed(0)
    critics = LayerNormCriticEnsemble(obs_dim=3, act_dim=2, hidden_sizes=(8, 8), n=4)
    with torch.no_grad():  # members get their own LayerNorm gains and biases
        for gain, bias in zip(critics.norm_gains, critics.norm_biases):
            gain.uniform_(0.5, 1.5)
            bias.uniform_(-0.1, 0.1)
    obs, act = torch.randn(5, 3), torch.randn(5, 2)
    q = critics(obs, act)
    assert q.shape == (4, 5)
    for member in range(4):
        x = torch.cat([obs, act], dim=-1)
        for k, (w, b) in enumerate(zip(critics.weights, critics.biases)):
            x = F.linear(x, w[member].T, b[member, 0])
            if k < 2:
                x = F.layer_norm(
                    x, (8,), critics.norm_gains[k][member, 0], critics.norm_biases[k][member, 0]
                )
                x = torch.relu(x)
        assert torch.allclose(q[member], x.squeeze(-1), atol=1e-5)
    assert len({round(v, 4) for v in q[:, 0].tolist()}) == 4


def constant_members(critics, values: list[float]) -> None:
    """Member i outputs values[i] whatever its input."""
    with torch.no_grad():
        for w, b in zip(critics.weights, critics.biases):
            w.zero_()
            b.zero_()
        critics.biases[-1][:, 0, 0] = torch.tensor(values)


@pytest.mark.parametrize("backup_entropy", [True, False])
def test_target_is_the_minimum_over_the_drawn_subset_of_target_critics(backup_entropy):
    config = RLPDConfig(hidden_sizes=(8, 8), backup_entropy=backup_entropy)
    agent = RLPDAgent(2, 1, -np.ones(1), np.ones(1), config, seed=0)
    assert agent.critics.n == 10 and isinstance(agent.critics, LayerNormCriticEnsemble)
    values = [5.0, 3.0, 8.0, -1.0, 7.0, 2.0, 9.0, 4.0, 6.0, 0.5]
    constant_members(agent.critics_target, values)
    next_obs, noise = torch.randn(4, 2), torch.randn(4, 1)
    alpha = torch.tensor(0.2)
    with torch.no_grad():
        _, log_prob = agent.policy.sample(next_obs, noise=noise)
    entropy_term = alpha * log_prob if backup_entropy else torch.zeros(4)
    for subset, expected in (([0, 2], 5.0), ([6, 4], 7.0), ([3, 9], -1.0)):
        value = agent.next_state_value(next_obs, noise, alpha, torch.tensor(subset))
        assert value.tolist() == pytest.approx((expected - entropy_term).tolist(), abs=1e-5)


def test_utd_critic_steps_on_fresh_subsets_then_one_actor_step():
    config = RLPDConfig(hidden_sizes=(8, 8), utd=3)
    assert config.gradient_steps == 3  # the shared loop's minibatches per env step
    agent = RLPDAgent(2, 1, -np.ones(1), np.ones(1), config, seed=0)
    subsets, actor_steps = [], []
    critic_step, actor_step = agent.critic_step, agent.actor_step
    agent.critic_step = lambda **kw: subsets.append(kw["subset"].tolist()) or critic_step(**kw)
    agent.actor_step = lambda **kw: actor_steps.append(len(subsets)) or actor_step(**kw)
    g = torch.Generator().manual_seed(0)
    batch = Batch(
        torch.randn(8, 2, generator=g),
        torch.rand(8, 1, generator=g) * 2 - 1,
        torch.randn(8, generator=g),
        torch.randn(8, 2, generator=g),
        torch.zeros(8),
    )
    for _ in range(6):  # two env steps' worth
        losses = agent.update(batch)
    assert actor_steps == [3, 6] and "policy_loss" in losses
    assert all(len(set(s)) == 2 and all(0 <= i < 10 for i in s) for s in subsets)
    assert len({tuple(sorted(s)) for s in subsets}) > 1  # drawn afresh


def test_rlpd_trains_on_half_demonstration_minibatches_deterministically(monkeypatch):
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    demo_states = {tuple(s) for s in demos.observations.tolist()}
    batches = []
    sample = SymmetricReplay.sample

    def recorded(self, batch_size, rng):
        batch = sample(self, batch_size, rng)
        batches.append(batch.observations.numpy().copy())
        return batch

    monkeypatch.setattr(SymmetricReplay, "sample", recorded)
    first, buffer = train_tiny("rlpd", seed=3, steps=300, utd=2)
    assert len(batches) == 2 * (300 - 100 + 1)  # utd minibatches per env step from step 100
    online_states = {tuple(s) for s in buffer.observations[: len(buffer)].tolist()}
    for rows in batches[::25]:
        assert all(tuple(s) in demo_states for s in rows[:8].tolist())
        assert all(tuple(s) in online_states for s in rows[8:].tolist())
    assert len(buffer) == 300  # the demonstrations stay out of the online buffer
    monkeypatch.undo()
    second, _ = train_tiny("rlpd", seed=3, steps=300, utd=2)
    assert curve_signature(first) == curve_signature(second)


def test_rlpd_explains_missing_transitions(monkeypatch):
    from replicate import demos as demos_module

    original = demos_module.load_demos

    def pairs_only(path, env_id):
        loaded = original(path, env_id)
        loaded.rewards = None
        return loaded

    monkeypatch.setattr("tests.helpers.load_demos", pairs_only)
    with pytest.raises(ValueError, match="needs demonstration transitions"):
        train_tiny("rlpd", steps=10)


def test_killed_rlpd_run_resumes_onto_the_uninterrupted_curve(tmp_path):
    # Hopper ends episodes quickly, which gives checkpoints before the kill
    overrides = {"hidden_sizes": (16, 16), "num_qs": 4}
    reference, reference_buffer, _ = run("rlpd", "Hopper-v5", 600, **overrides)
    checkpoint = tmp_path / "checkpoint.pt"
    with pytest.raises(Killed):
        run("rlpd", "Hopper-v5", 600, checkpoint_path=checkpoint, kill_at=450, **overrides)
    resumed, resumed_buffer, resumed_from = run(
        "rlpd", "Hopper-v5", 600, checkpoint_path=checkpoint, **overrides
    )
    assert 150 < resumed_from < 450
    assert curve_signature(resumed) == curve_signature(reference)
    assert np.array_equal(resumed_buffer.actions[:600], reference_buffer.actions[:600])
