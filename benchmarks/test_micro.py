"""Micro-benchmarks with pytest-benchmark: one gradient step per algorithm, one batched step,
one guidance query, one adapter step (Hopper-v5 sizes, one torch thread).

    pytest benchmarks/test_micro.py --benchmark-json reports/bench/micro.json

``nox -s bench`` runs them and saves the JSON; ``pytest-benchmark compare`` puts two
commits' files side by side.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.batched import StackedSACAgent, StackedTwinQAgent
from baselines.common.buffer import Batch, ReplayBuffer
from baselines.drl_eg import DRLEGConfig, Guidance
from baselines.sac import SACAgent, SACConfig
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from envs import make_env

OBS, ACT, ROWS = 11, 3, 256


@pytest.fixture(autouse=True)
def one_thread():
    torch.set_num_threads(1)


def _buffer() -> ReplayBuffer:
    buffer = ReplayBuffer(OBS, ACT, 10_000)
    rng = np.random.default_rng(0)
    for _ in range(10_000):
        buffer.add(
            rng.normal(size=OBS), rng.uniform(-1, 1, ACT), rng.normal(), rng.normal(size=OBS), False
        )
    return buffer


@pytest.mark.parametrize("algo", ["sac", "sac-twin-q"])
def test_gradient_step(benchmark, algo):
    cls, cfg = (SACAgent, SACConfig()) if algo == "sac" else (TwinQSACAgent, TwinQSACConfig())
    agent = cls(OBS, ACT, -np.ones(ACT), np.ones(ACT), cfg, seed=0)
    buffer, rng = _buffer(), np.random.default_rng(0)
    benchmark(lambda: agent.update(buffer.sample(ROWS, rng)))


@pytest.mark.parametrize("members", [1, 4])
@pytest.mark.parametrize("algo", ["sac", "sac-twin-q"])
def test_batched_gradient_step(benchmark, algo, members):
    cls, stacked, cfg = (
        (SACAgent, StackedSACAgent, SACConfig())
        if algo == "sac"
        else (TwinQSACAgent, StackedTwinQAgent, TwinQSACConfig())
    )
    agents = [cls(OBS, ACT, -np.ones(ACT), np.ones(ACT), cfg, seed=s) for s in range(members)]
    agent = stacked(agents, cfg, "cpu")
    g = torch.Generator().manual_seed(0)
    batch = Batch(
        torch.randn(members, ROWS, OBS, generator=g),
        torch.rand(members, ROWS, ACT, generator=g),
        torch.randn(members, ROWS, generator=g),
        torch.randn(members, ROWS, OBS, generator=g),
        torch.zeros(members, ROWS),
    )
    benchmark(lambda: agent._gradient_step(batch, agent._cpu_noise()))


def test_guidance_query(benchmark):
    from replicate.demos import default_demo_path, load_demos

    demos = load_demos(default_demo_path("Hopper-v5"), "Hopper-v5")
    guidance = Guidance(DRLEGConfig(guide_threshold=0.5), demos, -np.ones(ACT), np.ones(ACT), 0)
    states = demos.observations + np.random.default_rng(0).normal(0, 0.2, demos.observations.shape)
    cycle = iter(np.tile(states.astype(np.float32), (1000, 1)))
    benchmark(lambda: guidance.guide(next(cycle)))


def test_adapter_step(benchmark):
    env = make_env("Hopper-v5", seed=0)
    action = np.zeros(ACT, dtype=np.float32)

    def step():
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()

    benchmark(step)
