"""Seed-batched RLPD: each member trains as its one-run RLPD would, beside the others."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.batched import StackedRLPDAgent
from baselines.common.stacked import StackedSymmetricReplay
from baselines.ibrl import preloaded_buffer
from baselines.rlpd import RLPDAgent, RLPDConfig, SymmetricReplay
from replicate.demos import default_demo_path, load_demos
from replicate.runner import execute, execute_batch, prepare
from replicate.spec import RunSpec
from tests.helpers import (
    MOUNTAINCAR,
    TINY,
    assert_batch_policies_agree,
    assert_batch_updates_agree,
    batch_curves,
)

OBS, ACT, ROWS, SEEDS, CAPACITY = 2, 1, 32, (0, 1, 2), 200
LOW, HIGH = -np.ones(ACT), np.ones(ACT)


def _demos():
    return load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)


def _transitions(rng: np.random.Generator, n: int):
    return (
        rng.normal(size=(n, OBS)).astype(np.float32),
        rng.uniform(-1, 1, size=(n, ACT)).astype(np.float32),
        rng.normal(size=n).astype(np.float32),
        rng.normal(size=(n, OBS)).astype(np.float32),
        rng.random(n) < 0.1,
    )


def _filled(demos, steps: int = 60):
    """The stacked replay and each member's one-run replay, holding the same transitions."""
    stacked = StackedSymmetricReplay(
        preloaded_buffer(demos, OBS, ACT, online_capacity=0),
        len(SEEDS),
        OBS,
        ACT,
        CAPACITY,
        torch.device("cpu"),
    )
    singles = [SymmetricReplay(demos, OBS, ACT, CAPACITY) for _ in SEEDS]
    rng = np.random.default_rng(3)
    for _ in range(steps):
        obs, act, rew, nxt, term = _transitions(rng, len(SEEDS))
        stacked.add(obs, act, rew, nxt, term)
        for k, buffer in enumerate(singles):
            buffer.add(obs[k], act[k], float(rew[k]), nxt[k], bool(term[k]))
    return stacked, singles


def test_stacked_symmetric_sample_draws_each_members_one_run_rows():
    stacked, singles = _filled(_demos())
    batch = stacked.sample(ROWS, [np.random.default_rng(s) for s in SEEDS])
    for k, (buffer, seed) in enumerate(zip(singles, SEEDS)):
        one = buffer.sample(ROWS, np.random.default_rng(seed))
        for name in ("observations", "actions", "rewards", "next_observations", "terminated"):
            assert torch.equal(getattr(batch, name)[k], getattr(one, name)), name
    demo_obs = torch.from_numpy(np.asarray(_demos().observations, dtype=np.float32))
    first_half = batch.observations[:, : ROWS // 2]  # the demonstration half comes first
    assert all(bool((demo_obs == row).all(-1).any()) for row in first_half.reshape(-1, OBS))


@pytest.mark.parametrize("utd", [1, 2])
def test_batched_rlpd_updates_equal_one_run_updates(utd):
    """Six updates of a batch of 3 (its own replay rows, noise and critic subsets drawn in
    each member's one-run order) against the one-run agents: losses, then weights, within
    1e-5; with utd 2 every other update is critic-only in both."""
    demos = _demos()
    config = RLPDConfig(hidden_sizes=(32, 32), batch_size=ROWS, utd=utd)
    singles = [RLPDAgent(OBS, ACT, LOW, HIGH, config, seed=s, cuda_graphs=False) for s in SEEDS]
    stacked = StackedRLPDAgent(
        [RLPDAgent(OBS, ACT, LOW, HIGH, config, seed=s, cuda_graphs=False) for s in SEEDS],
        config,
        preloaded_buffer(demos, OBS, ACT, online_capacity=0),
        "cpu",
    )
    stacked.buffer, buffers = _filled(demos)
    assert_batch_updates_agree(stacked, singles, buffers, ROWS, SEEDS, updates=6)
    assert stacked.critic_updates == 6
    assert_batch_policies_agree(stacked, singles)
    for k, agent in enumerate(singles):
        rows = slice(k * config.num_qs, (k + 1) * config.num_qs)
        for mine, theirs in (
            (stacked.critics, agent.critics),
            (stacked.critics_target, agent.critics_target),
        ):
            named = dict(theirs.named_parameters())  # the target's LayerNorm too
            assert len(named) == len(list(mine.parameters()))
            for name, value in mine.named_parameters():
                assert torch.allclose(value[rows], named[name], atol=1e-6), name
        assert torch.allclose(stacked.log_alpha[k], agent.log_alpha[0], atol=1e-6)


def _specs(seeds=(0, 1), steps: int = 400, **hyper):
    return [RunSpec("rlpd", MOUNTAINCAR, seed, steps, 200, 1, {**TINY, **hyper}) for seed in seeds]


def test_a_batched_rlpd_run_lands_on_its_one_run_curve(tmp_path):
    """Seed 1 trained in a batch beside seed 0 and alone: the same address and, on CPU,
    the same evaluation returns (to the printed digits)."""
    batch = execute_batch([prepare(s) for s in _specs()], tmp_path / "batch", device="cpu")
    alone = execute(prepare(_specs(seeds=(1,))[0]), tmp_path / "alone", device="cpu")
    assert not batch.failed and batch.runs[1].path.name == alone.path.name
    np.testing.assert_allclose(
        batch.runs[1].curve["return_mean"], alone.curve["return_mean"], rtol=1e-4, atol=1e-3
    )
    assert batch.runs[0].curve["returns"].tolist() != batch.runs[1].curve["returns"].tolist()


def test_an_interrupted_rlpd_batch_resumes_onto_the_uninterrupted_curves(tmp_path):
    config = RLPDConfig(**TINY)
    whole = batch_curves("rlpd", config, tmp_path / "whole.pt")
    batch_curves("rlpd", config, tmp_path / "cut.pt", stop_at=250)
    resumed = batch_curves("rlpd", config, tmp_path / "cut.pt")
    for k in (0, 1):
        assert [(p.step, p.returns) for p in resumed[k]] == [(p.step, p.returns) for p in whole[k]]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("utd", [1, 2])  # 2: the critic-only steps' graph too
def test_a_batched_rlpd_trains_on_the_gpu_with_graphs(tmp_path, utd):
    members = [prepare(s) for s in _specs(seeds=(0, 1), steps=600, utd=utd)]
    outcome = execute_batch(members, tmp_path, device="cuda")
    assert not outcome.failed and len(outcome.runs) == 2
