"""The contract test kit: every algorithm the registry finds that trains in seed batches (the
SAC family, ``baselines.contract``) gets these checks without writing a test of its own.

For each, one module-scoped set of tiny trainings on MountainCar (hidden (16, 16), batch 16,
400 steps) is shared by the checks: a seed batch of two checkpointing every 100 steps and
keeping each member's best policy; seed 0 alone; and the batch resumed from its last
checkpoint (step 300), as it would be after a kill there. Then:

- a member trains as its seed alone does, to rounding (weights within 1e-5, returns within
  a relative 1e-5: a stack of one rounds its products unlike a stack of two);
- kill-and-resume ends where the uninterrupted batch ends, bit for bit: curves, replay,
  and everything the agent's checkpoint holds;
- a checkpoint round-trips: loading it and saving again gives it back;
- ``keep_best_policy`` keeps each member's best evaluation, as a one-run policy;
- bad settings fail in one line;
- and the rules catch a wrongly written agent: noise drawn from the global generator inside
  the gradient step or while acting, or a network left out of the checkpoint.

docs/adding-an-algorithm.md says how a new algorithm is held to this.
"""

from __future__ import annotations

import io
import json
import lzma
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from baselines.common.checkpoint import load_checkpoint
from baselines.common.context import BatchContext, TrainContext
from baselines.contract import (
    STRICT_RANDOMNESS,
    AgentContract,
    ContractError,
    ReproducibilityError,
    agent_state,
    load_agent_state,
)
from baselines.offpolicy import train_members
from baselines.registry import batchable_algorithms, get_algorithm
from baselines.sac import SACAgent
from baselines.sac_twin_q import TwinQSACAgent
from replicate.errors import HarnessError
from tests.helpers import (
    MOUNTAINCAR,
    assert_members_agree,
    built_agents,
    curve_signature,
    tiny_config,
    train_batch,
    train_tiny,
)

try:  # the harness's run preparation (replicate/ is being split into subpackages)
    from replicate.store.runner import prepare
    from replicate.store.spec import RunSpec
except ImportError:  # pragma: no cover
    from replicate.runner import prepare
    from replicate.spec import RunSpec

STEPS = 400  # the batch checkpoints at steps 100, 200 and 300
ALGORITHMS = batchable_algorithms()


class Trained:
    """One algorithm's shared trainings (see the module docstring)."""

    def __init__(self, algo: str, root):
        config = tiny_config(algo)
        self.algo, self.root = algo, root
        self.whole = train_batch(algo, config, root / "whole.pt", steps=STEPS, keep_best=root)
        with built_agents() as built:
            self.alone_curve, _ = train_tiny(algo, seed=0, steps=STEPS)
        self.alone = built[-1]
        # what a kill after step 300 leaves on disk is the checkpoint of step 300
        shutil.copy(root / "whole.pt", root / "killed.pt")
        self.resumed = train_batch(algo, config, root / "killed.pt", steps=STEPS)


@pytest.fixture(scope="module", params=ALGORITHMS)
def trained(request, tmp_path_factory) -> Trained:
    torch.set_num_threads(1)  # as training sets it: the agents are compared afterwards
    return Trained(request.param, tmp_path_factory.mktemp(request.param))


def assert_same_state(a, b, where: str = "state") -> None:
    """Two checkpoint states (nested dicts, lists, tensors, arrays, numbers) equal bit for bit."""
    if isinstance(a, torch.Tensor):
        assert a.shape == b.shape and a.dtype == b.dtype, where
        assert torch.equal(a.reshape(-1).view(torch.uint8), b.reshape(-1).view(torch.uint8)), where
    elif isinstance(a, np.ndarray):
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), where
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            assert_same_state(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_state(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), where
    else:
        assert a == b, where


# --- what every batchable algorithm gets -------------------------------------------------------


def test_a_batch_evaluates_each_member_on_its_own_curve(trained):
    curves = trained.whole.curves
    assert isinstance(trained.whole.agent, AgentContract)
    assert [p.step for p in curves[0]] == [p.step for p in curves[1]] == [0, 200, 400]
    assert curve_signature(curves[0]) != curve_signature(curves[1])


def test_a_member_trains_as_its_seed_alone(trained):
    """Member 0 of the batch of seeds (0, 1) against seed 0 trained alone: every network
    (and learned tensor) within 1e-5, the curve within a relative 1e-5."""
    batch, alone = trained.whole.agent, trained.alone
    for name in batch.MODULES:
        if isinstance(getattr(batch, name), nn.Module):
            per_member = next(getattr(alone, name).parameters()).shape[0]  # a stack of one
            assert_members_agree(batch, [alone], name, per_member)
    ours, theirs = trained.whole.curves[0], trained.alone_curve
    assert [p.step for p in ours] == [p.step for p in theirs]
    for mine, own in zip(ours, theirs):
        for got, want in (
            (mine.returns, own.returns),
            (mine.guided_fraction, own.guided_fraction),
            (mine.train_return, own.train_return),
        ):
            assert got == pytest.approx(want, rel=1e-5, abs=1e-6, nan_ok=True)


def test_kill_and_resume_ends_on_the_uninterrupted_run(trained):
    whole, resumed = trained.whole, trained.resumed
    assert resumed.resumed_from == 300
    for seed in (0, 1):
        assert curve_signature(resumed.curves[seed]) == curve_signature(whole.curves[seed])
    assert_same_state(resumed.replay.state_dict(), whole.replay.state_dict(), "replay")
    assert_same_state(agent_state(resumed.agent), agent_state(whole.agent), "agent")


def test_a_checkpoint_round_trips(trained):
    """The agent's part of a checkpoint on disk, loaded into an agent and taken out again,
    is what was saved, under the names the contract declares."""
    agent = trained.resumed.agent
    saved = load_checkpoint(trained.root / "whole.pt")["agent"]
    assert list(saved) == [*agent.MODULES, *agent.TENSORS, "noise", "extra"]
    now = agent_state(agent)
    load_agent_state(agent, saved)
    try:
        assert_same_state(agent_state(agent), saved, "agent")
    finally:
        load_agent_state(agent, now)


def test_keep_best_policy_keeps_each_members_best_evaluation(trained):
    agent = trained.whole.agent
    for k, seed in enumerate((0, 1)):
        curve = trained.whole.curves[seed]
        best = max(curve, key=lambda p: p.mean_return)  # the first of equals
        kept = torch.load(trained.root / f"best-{seed}.pt", weights_only=True)
        assert (kept["step"], kept["mean_return"]) == (best.step, best.mean_return)
        policy = agent.policy.member_policy(k)  # the one-run policy an expert file holds
        policy.load_state_dict(kept["policy"])
        if best.step == curve[-1].step:  # then it holds the member's weights now
            obs = np.zeros(policy.trunk[0].in_features, dtype=np.float32)
            with torch.no_grad():
                acted = policy.deterministic(torch.from_numpy(obs)[None])[0].numpy()
            np.testing.assert_allclose(acted, agent.act_member_deterministic(k, obs), atol=1e-6)


BAD_SETTINGS = (
    {"no_such_setting": 1},
    {"batch_size": 0},
    {"gradient_steps": 0},
    {"hidden_sizes": "wide"},
)


@pytest.mark.parametrize("algo", ALGORITHMS)
@pytest.mark.parametrize("bad", BAD_SETTINGS, ids=lambda bad: next(iter(bad)))
def test_bad_settings_fail_in_one_line(algo, bad):
    with pytest.raises(HarnessError) as refused:
        prepare(RunSpec(algo, MOUNTAINCAR, 0, STEPS, 200, 1, bad))
    message = str(refused.value)
    assert algo in message and "\n" not in message


CARRIED = sorted((Path(__file__).resolve().parents[1] / "runs" / "carry").glob("batch-*"))


@pytest.mark.skipif(not CARRIED, reason="no carried checkpoint is committed")
def test_a_committed_checkpoint_loads_into_todays_agent():
    """A seed batch's checkpoint carried in the repository (V-network SAC's: SAC or DRL-EG)
    loads into the agent built from its runs' settings, and is what it gives back."""
    carried = CARRIED[-1]
    spec = json.loads(next((carried / "partial").glob("*/spec.json")).read_text())
    manifest = json.loads((carried / "manifest.json").read_text())
    state = torch.load(
        io.BytesIO(lzma.open(carried / "state.pt.xz").read()),
        weights_only=False,
        map_location="cpu",
    )["agent"]
    config = get_algorithm(spec["algo"]).make_config(spec["hyperparameters"])
    agent = SACAgent(manifest["seeds"], manifest["env_id"], config, cuda_graphs=False)
    load_agent_state(agent, state)
    assert_same_state(agent_state(agent), state, "agent")


# --- the rules catch a wrongly written agent ---------------------------------------------------


class GlobalNoiseInTheStep(TwinQSACAgent):
    """Draws s' noise CleanRL-style inside its gradient step, from torch's global generator:
    a member's numbers would then depend on its batch."""

    def gradient_step(self, batch, noise, kind="full", **inputs):
        next_noise = torch.randn_like(batch.actions)
        return super().gradient_step(batch, (next_noise, noise[1]), kind, **inputs)


class GlobalNoiseWhileActing(TwinQSACAgent):
    """Explores with noise of its own making rather than the member streams' draw."""

    def explore(self, obs, noise):
        return super().explore(obs, torch.randn_like(noise))


@pytest.mark.parametrize(
    "agent_cls, caught",
    [(GlobalNoiseInTheStep, "gradient step"), (GlobalNoiseWhileActing, "choice of")],
)
def test_the_trainer_refuses_noise_from_the_global_generator(monkeypatch, agent_cls, caught):
    monkeypatch.setenv(STRICT_RANDOMNESS, "1")
    config = tiny_config("sac-twin-q")
    contexts = [TrainContext(MOUNTAINCAR, seed, STEPS, 200, 1) for seed in (0, 1)]
    agent = agent_cls([0, 1], MOUNTAINCAR, config, cuda_graphs=False)
    with pytest.raises(ReproducibilityError, match="torch's global random generator") as drew:
        train_members(BatchContext(contexts), agent)
    assert agent_cls.__name__ in str(drew.value) and caught in str(drew.value)


class ForgetsANetwork(TwinQSACAgent):
    def build(self, obs_dim, low, high):
        super().build(obs_dim, low, high)
        self.value_head = nn.Linear(obs_dim, 1)  # learned, but not in MODULES


def test_a_network_the_checkpoint_would_miss_is_refused_when_built():
    with pytest.raises(ContractError, match="value_head would not be checkpointed"):
        ForgetsANetwork([0], MOUNTAINCAR, tiny_config("sac-twin-q"), cuda_graphs=False)
