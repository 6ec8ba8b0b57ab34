import numpy as np
import pytest
import torch
from torch.nn import functional as F

from baselines.common.buffer import Batch
from baselines.common.stacked import StackedNormMLP, StackedSymmetricReplay, critic_ensembles
from baselines.contract import FULL_STEP
from baselines.ibrl import preloaded_buffer
from baselines.rlpd import CRITIC_STEP, LayerNormCriticEnsemble, RLPDAgent, RLPDConfig
from replicate.demos import Demonstrations, default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR, curve_signature, train_tiny

OBS, ACT = 2, 1  # MountainCar's
CPU = torch.device("cpu")


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


def demo_buffer(demos: Demonstrations | None = None):
    """The demonstrations as RLPD's trainer hands them to the agent."""
    return preloaded_buffer(demos or marked_demos(), OBS, ACT, online_capacity=0)


def rlpd_agent(seeds=(0,), **settings) -> RLPDAgent:
    config = RLPDConfig(hidden_sizes=(8, 8), **settings)
    return RLPDAgent(list(seeds), MOUNTAINCAR, config, demo_buffer(), cuda_graphs=False)


def test_every_sample_is_exactly_half_demonstrations():
    members = 2
    replay = StackedSymmetricReplay(demo_buffer(), members, OBS, ACT, capacity=50, device=CPU)
    for t in range(7):  # member k's online states are 50 k + t
        obs = np.array([[50.0 * k + t] * OBS for k in range(members)], np.float32)
        replay.add(obs, np.zeros((members, ACT)), np.zeros(members), obs + 1, np.zeros(members))
    rngs = [np.random.default_rng(seed) for seed in range(members)]
    for batch_size in (2, 16, 64):
        batch = replay.sample(batch_size, rngs)
        half = batch_size // 2
        assert batch.rewards.shape == (members, batch_size)
        for k in range(members):
            assert batch.rewards[k, :half].tolist() == [1.0] * half  # demonstrations first
            assert batch.rewards[k, half:].tolist() == [0.0] * (batch_size - half)
            assert (batch.observations[k, :half] >= 100).all()
            online = batch.observations[k, half:]  # each member's own online rows
            assert ((online >= 50 * k) & (online < 50 * k + 7)).all()
    assert replay.size == 7  # the demonstrations are not in the online rows
    with pytest.raises(ValueError, match="must be even"):
        RLPDConfig(batch_size=15)


def test_layer_norm_ensemble_is_independent_normalised_mlps():
    seeds, q, hidden = (0, 1), 4, (8, 8)
    agent = rlpd_agent(seeds, num_qs=q)
    critics = agent.critics
    assert isinstance(critics, StackedNormMLP) and critics.members == len(seeds) * q
    g = torch.Generator().manual_seed(0)
    obs, act = torch.randn(2, 5, OBS, generator=g), torch.randn(2, 5, ACT, generator=g)
    # at the start, member k's critics are the LayerNorm ensemble its seed draws
    for k, seed in enumerate(seeds):
        ensemble, _ = agent.member_networks(seed, OBS, ACT, -np.ones(ACT), np.ones(ACT))
        assert isinstance(ensemble, LayerNormCriticEnsemble)
        with torch.no_grad():
            expected = ensemble(obs[k], act[k])
            got = critic_ensembles(critics, obs, act, q)[k]
        assert torch.allclose(got, expected, atol=1e-6)
    with torch.no_grad():  # every critic gets its own LayerNorm gains and biases
        for gain, bias in zip(critics.norm_gains, critics.norm_biases):
            gain.uniform_(0.5, 1.5, generator=g)
            bias.uniform_(-0.1, 0.1, generator=g)
        values = critic_ensembles(critics, obs, act, q)
    assert values.shape == (2, q, 5)
    for k in range(2):
        for i in range(q):
            c = k * q + i  # member-major
            x = torch.cat([obs[k], act[k]], dim=-1)
            for layer, (w, b) in enumerate(zip(critics.weights, critics.biases)):
                x = F.linear(x, w[c].T, b[c, 0])
                if layer < len(hidden):
                    gain, bias = critics.norm_gains[layer][c, 0], critics.norm_biases[layer][c, 0]
                    x = torch.relu(F.layer_norm(x, (hidden[layer],), gain, bias))
            assert torch.allclose(values[k, i], x.squeeze(-1), atol=1e-5)
    assert len({round(v, 4) for v in values[:, :, 0].flatten().tolist()}) == 2 * q


def constant_critics(critics, values: list[float]) -> None:
    """Critic c of the stack (member-major) outputs values[c] whatever its input."""
    with torch.no_grad():
        for w, b in zip(critics.weights, critics.biases):
            w.zero_()
            b.zero_()
        critics.biases[-1][:, 0, 0] = torch.tensor(values)


@pytest.mark.parametrize("backup_entropy", [True, False])
def test_target_is_the_minimum_over_the_drawn_subset_of_target_critics(backup_entropy):
    agent = rlpd_agent((0, 1), backup_entropy=backup_entropy)
    assert agent.per_member == 10 and isinstance(agent.critics, StackedNormMLP)
    values = [5.0, 3.0, 8.0, -1.0, 7.0, 2.0, 9.0, 4.0, 6.0, 0.5]  # member 0's; 1's reversed
    g = torch.Generator().manual_seed(1)
    rows, gamma, reward = 4, agent.config.gamma, 20.0
    for subsets, expected in (
        ([[0, 2], [1, 2]], [5.0, 4.0]),
        ([[6, 4], [9, 1]], [7.0, 5.0]),
        ([[3, 9], [6, 3]], [-1.0, -1.0]),
    ):
        constant_critics(agent.critics_target, [*values, *values[::-1]])
        constant_critics(agent.critics, [0.0] * 20)  # Q = 0: the loss is the mean of y^2
        next_obs = torch.randn(2, rows, OBS, generator=g)
        next_noise, new_noise = torch.randn(2, rows, ACT, generator=g), torch.zeros(2, rows, 1)
        batch = Batch(
            torch.randn(2, rows, OBS, generator=g),
            torch.rand(2, rows, ACT, generator=g) * 2 - 1,
            torch.full((2, rows), reward),
            next_obs,
            torch.zeros(2, rows),
        )
        alpha = agent.log_alpha.detach().exp()[:, None]
        with torch.no_grad():
            _, log_prob = agent.policy.sample(next_obs, noise=next_noise)
        entropy = alpha * log_prob if backup_entropy else torch.zeros(2, rows)
        y = reward + gamma * (torch.tensor(expected)[:, None] - entropy)
        noise = (next_noise, torch.tensor(subsets), new_noise)
        losses = agent.gradient_step(batch, noise, CRITIC_STEP)
        assert losses["q_loss"].tolist() == pytest.approx(y.pow(2).mean(-1).tolist(), rel=1e-5)


def test_utd_critic_steps_on_fresh_subsets_then_one_actor_step():
    config = RLPDConfig(hidden_sizes=(8, 8), utd=3)
    assert config.gradient_steps == 3  # the shared loop's minibatches per env step
    agent = RLPDAgent([0, 1], MOUNTAINCAR, config, demo_buffer(), cuda_graphs=False)
    agent.buffer = agent.make_replay(2, OBS, 50)
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs = rng.normal(size=(2, OBS)).astype(np.float32)
        agent.buffer.add(obs, rng.uniform(-1, 1, (2, ACT)), rng.normal(size=2), obs, np.zeros(2))
    subsets, steps = [], []
    rlpd_step = agent.gradient_step

    def recorded(batch, noise, kind):
        subsets.append(noise[1].tolist())
        steps.append(kind == FULL_STEP)
        return rlpd_step(batch, noise, kind)

    agent.gradient_step = recorded
    rngs = [np.random.default_rng(s) for s in (0, 1)]
    policy = [p.detach().clone() for p in agent.policy.parameters()]
    critics = [p.detach().clone() for p in agent.critics.parameters()]
    keys = []
    for _ in range(6):  # two env steps' worth
        losses = agent.update(rngs)
        keys.append("policy_loss" in losses)
        moved = any(not torch.equal(a, b) for a, b in zip(policy, agent.policy.parameters()))
        assert moved == keys[-1]  # the actor steps only with the last critic step
        assert any(not torch.equal(a, b) for a, b in zip(critics, agent.critics.parameters()))
        policy = [p.detach().clone() for p in agent.policy.parameters()]
        critics = [p.detach().clone() for p in agent.critics.parameters()]
    assert keys == steps == [False, False, True, False, False, True]
    assert agent.critic_updates == 6
    assert set(losses) == {"q_loss", "policy_loss", "alpha", "entropy"}
    per_member = [s for step in subsets for s in step]
    assert all(len(set(s)) == 2 and all(0 <= i < 10 for i in s) for s in per_member)
    for k in range(2):  # each member draws its subsets afresh
        assert len({tuple(sorted(step[k])) for step in subsets}) > 1


def test_rlpd_trains_on_half_demonstration_minibatches_deterministically(monkeypatch):
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    demo_states = {tuple(s) for s in demos.observations.tolist()}
    batches = []
    sample = StackedSymmetricReplay.sample

    def recorded(self, batch_size, rngs):
        batch = sample(self, batch_size, rngs)
        batches.append(batch.observations[0].numpy().copy())
        return batch

    monkeypatch.setattr(StackedSymmetricReplay, "sample", recorded)
    first, replay = train_tiny("rlpd", seed=3, steps=300, utd=2)
    assert len(batches) == 2 * (300 - 100 + 1)  # utd minibatches per env step from step 100
    buffer = replay.member(0)
    online_states = {tuple(s) for s in buffer.observations.tolist()}
    for rows in batches[::25]:
        assert all(tuple(s) in demo_states for s in rows[:8].tolist())
        assert all(tuple(s) in online_states for s in rows[8:].tolist())
    assert replay.size == 300  # the demonstrations stay out of the online buffer
    assert len(replay.demos) == len(demos.observations)
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
