import copy
import math

import torch
from torch.nn import functional as F

from baselines.common.buffer import Batch
from baselines.contract import agent_state, load_agent_state
from baselines.sac_twin_q import CriticEnsemble, TwinQSACAgent, TwinQSACConfig
from tests.helpers import MOUNTAINCAR, train_tiny


def test_critic_ensemble_is_independent_mlps_evaluated_together():
    torch.manual_seed(0)
    critics = CriticEnsemble(obs_dim=3, act_dim=2, hidden_sizes=(8, 8), n=2)
    obs, act = torch.randn(5, 3), torch.randn(5, 2)
    q = critics(obs, act)
    assert q.shape == (2, 5)
    for member in range(2):
        x = torch.cat([obs, act], dim=-1)
        for k, (w, b) in enumerate(zip(critics.weights, critics.biases)):
            x = F.linear(x, w[member].T, b[member, 0])
            x = torch.relu(x) if k < 2 else x
        assert torch.allclose(q[member], x.squeeze(-1), atol=1e-6)
    assert not torch.allclose(q[0], q[1])  # two members, two initialisations


def _agent_and_batch(seed: int = 0):
    config = TwinQSACConfig(hidden_sizes=(32, 32), learning_rate=3e-3)
    agent = TwinQSACAgent([seed], MOUNTAINCAR, config)
    g = torch.Generator().manual_seed(seed)
    batch = Batch(
        torch.randn(1, 64, 2, generator=g),
        torch.rand(1, 64, 1, generator=g) * 2 - 1,
        torch.randn(1, 64, generator=g),
        torch.randn(1, 64, 2, generator=g),
        torch.zeros(1, 64),
    )
    return agent, batch


def _update(agent, batch, step: int) -> dict[str, float]:
    g = torch.Generator().manual_seed(step)  # the same noise for any agent at this step
    noise = (torch.randn(1, 64, 1, generator=g), torch.randn(1, 64, 1, generator=g))
    return {name: float(value[0]) for name, value in agent.gradient_step(batch, noise).items()}


def test_update_fits_the_critics_and_tunes_the_temperature_towards_the_target_entropy():
    agent, batch = _agent_and_batch()
    history = [_update(agent, batch, step) for step in range(80)]
    assert all(math.isfinite(h["q_loss"]) for h in history)
    assert history[-1]["q_loss"] < history[0]["q_loss"]
    # a fresh policy is far more random than the target entropy (-1 for one action
    # dimension), so the temperature must fall
    assert history[0]["entropy"] > agent.target_entropy
    assert agent.log_alpha.exp().item() < history[0]["alpha"] == 1.0


def test_state_dict_round_trip_continues_identically():
    agent, batch = _agent_and_batch()
    for step in range(5):
        _update(agent, batch, step)
    state = copy.deepcopy(agent_state(agent))  # as a checkpoint on disk would hold it
    twin, _ = _agent_and_batch(seed=1)
    load_agent_state(twin, state)
    assert _update(agent, batch, 5) == _update(twin, batch, 5)


def test_same_seed_same_curve_on_cpu():
    first, _ = train_tiny("sac-twin-q", seed=3, steps=400)
    second, _ = train_tiny("sac-twin-q", seed=3, steps=400)
    assert [p.returns for p in first] == [p.returns for p in second]
