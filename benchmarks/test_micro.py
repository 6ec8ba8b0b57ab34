"""Micro-benchmarks with pytest-benchmark: one gradient step per algorithm (from the replay,
as training takes it), one step of a seed batch of 1 and of 4 members on a fixed minibatch,
one guidance query, one adapter step (Hopper-v5 sizes, one torch thread).

    pytest benchmarks/test_micro.py --benchmark-json reports/bench/micro.json

``nox -s bench`` runs them and saves the JSON; ``pytest-benchmark compare`` puts two
commits' files side by side. A single run is a seed batch of one
(``baselines.offpolicy``), so ``test_batched_gradient_step[...-1]`` is its step.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.common.buffer import Batch
from baselines.drl_eg import DRLEGConfig, GuidedExplorer, functional_guider
from baselines.sac import SACAgent, SACConfig
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from envs import make_env

ENV, OBS, ACT, ROWS = "Hopper-v5", 11, 3, 256


@pytest.fixture(autouse=True)
def one_thread():
    torch.set_num_threads(1)


def _agent(algo: str, members: int):
    cls, cfg = (SACAgent, SACConfig()) if algo == "sac" else (TwinQSACAgent, TwinQSACConfig())
    return cls(list(range(members)), ENV, cfg)


def _fill(agent, transitions: int = 10_000) -> None:
    """The agent's replay, full of random transitions (each member its own)."""
    n = agent.members
    agent.buffer = agent.make_replay(n, OBS, transitions)
    rng = np.random.default_rng(0)
    for _ in range(transitions):
        agent.buffer.add(
            rng.normal(size=(n, OBS)).astype(np.float32),
            rng.uniform(-1, 1, size=(n, ACT)).astype(np.float32),
            rng.normal(size=n).astype(np.float32),
            rng.normal(size=(n, OBS)).astype(np.float32),
            np.zeros(n, dtype=np.float32),
        )


@pytest.mark.parametrize("algo", ["sac", "sac-twin-q"])
def test_gradient_step(benchmark, algo):
    agent = _agent(algo, 1)
    _fill(agent)
    rngs = [np.random.default_rng(0)]
    benchmark(lambda: agent.update(rngs))


@pytest.mark.parametrize("members", [1, 4])
@pytest.mark.parametrize("algo", ["sac", "sac-twin-q"])
def test_batched_gradient_step(benchmark, algo, members):
    agent = _agent(algo, members)
    g = torch.Generator().manual_seed(0)
    batch = Batch(
        torch.randn(members, ROWS, OBS, generator=g),
        torch.rand(members, ROWS, ACT, generator=g),
        torch.randn(members, ROWS, generator=g),
        torch.randn(members, ROWS, OBS, generator=g),
        torch.zeros(members, ROWS),
    )
    benchmark(lambda: agent.gradient_step(batch, agent.cpu_noise()))


def test_guidance_query(benchmark):
    """DRL-EG's guidance for one member's state, gate open: D(s) (a KD-tree query bounded
    by T2) and, where it guides, G(s) (the nearest demonstration's action plus noise)."""
    from replicate.demos import default_demo_path, load_demos

    demos = load_demos(default_demo_path(ENV), ENV)
    config = DRLEGConfig(guide_threshold=0.5)
    low, high = -np.ones(ACT), np.ones(ACT)
    explorer = GuidedExplorer(_agent("sac", 1), [config], demos, low, high, [0])
    states = demos.observations + np.random.default_rng(0).normal(0, 0.2, demos.observations.shape)
    cycle = iter(np.tile(states.astype(np.float32), (1000, 1))[:, None, :])
    gate = np.ones(1, dtype=bool)

    def guide() -> np.ndarray | None:
        guided, index = explorer.decide(next(cycle), gate)
        if not guided[0]:
            return None
        return functional_guider(
            explorer.demo_actions, index[0], config.guide_noise_std, explorer.rngs[0], low, high
        )

    benchmark(guide)


def test_adapter_step(benchmark):
    env = make_env(ENV, seed=0)
    action = np.zeros(ACT, dtype=np.float32)

    def step():
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()

    benchmark(step)
