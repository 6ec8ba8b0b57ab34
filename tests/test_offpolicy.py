"""The seed-batched trainer: each member is the one-run path's run, trained beside others."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from baselines.batched import (
    BatchContext,
    StackedGuidedExplorer,
    StackedSACAgent,
    StackedTwinQAgent,
    agent_state,
    evaluate_members,
    load_agent_state,
)
from baselines.common.buffer import Batch
from baselines.common.context import TrainContext
from baselines.common.evaluation import evaluate
from baselines.drl_eg import DRLEGConfig, Guidance
from baselines.registry import batched_trainer, get_algorithm
from baselines.sac import SACAgent, SACConfig
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from envs import make_env
from envs.vector import EnvBatch
from replicate.demos import default_demo_path, load_demos
from replicate.runner import execute_batch, is_complete, prepare
from replicate.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY, curve_signature, train_tiny

OBS, ACT, ROWS, SEEDS = 11, 3, 32, (0, 1, 2)
ROOT = Path(__file__).resolve().parents[1]


def _agents(agent_cls, config, seeds=SEEDS):
    return [
        agent_cls(OBS, ACT, -np.ones(ACT), np.ones(ACT), config, seed=s, cuda_graphs=False)
        for s in seeds
    ]


def _minibatches(generator: torch.Generator) -> Batch:
    n = len(SEEDS)
    return Batch(
        torch.randn(n, ROWS, OBS, generator=generator),
        torch.rand(n, ROWS, ACT, generator=generator) * 2 - 1,
        torch.randn(n, ROWS, generator=generator),
        torch.randn(n, ROWS, OBS, generator=generator),
        (torch.rand(n, ROWS, generator=generator) < 0.2).float(),
    )


def _member(batch: Batch, k: int) -> Batch:
    return Batch(*[t[k] for t in vars(batch).values()])


@pytest.mark.parametrize("twin_q", [False, True])
def test_batched_step_equals_one_run_steps(twin_q):
    """Three gradient steps of a batch of 3 on given minibatches and noise against the
    one-run agents of the same seeds on the same numbers: losses and weights within 1e-5."""
    config = (TwinQSACConfig if twin_q else SACConfig)(hidden_sizes=(32, 32), batch_size=ROWS)
    agent_cls = TwinQSACAgent if twin_q else SACAgent
    singles = _agents(agent_cls, config)
    stacked = (StackedTwinQAgent if twin_q else StackedSACAgent)(
        _agents(agent_cls, config), config, "cpu"
    )
    generator = torch.Generator().manual_seed(7)
    for _ in range(3):
        batch = _minibatches(generator)
        noises = [
            torch.randn(len(SEEDS), ROWS, ACT, generator=generator)
            for _ in range(2 if twin_q else 1)
        ]
        losses = stacked._gradient_step(batch, tuple(noises) if twin_q else noises[0])
        for k, agent in enumerate(singles):
            one = _member(batch, k)
            inputs = dict(
                obs=one.observations,
                actions=one.actions,
                rewards=one.rewards,
                next_obs=one.next_observations,
                terminated=one.terminated,
            )
            if twin_q:
                reference = agent._gradient_step(
                    **inputs, next_noise=noises[0][k], new_noise=noises[1][k]
                )
            else:
                reference = agent._gradient_step(**inputs, noise=noises[0][k])
            for name in ("q_loss", "policy_loss", "entropy"):
                assert float(losses[name][k]) == pytest.approx(
                    float(reference[name]), abs=1e-5, rel=1e-5
                )
    for k, agent in enumerate(singles):
        for (weight, bias), layer in zip(
            stacked.policy.trunk.member_linear(k),
            [m for m in agent.policy.trunk if isinstance(m, torch.nn.Linear)],
        ):
            assert torch.allclose(weight, layer.weight, atol=1e-5)
            assert torch.allclose(bias, layer.bias, atol=1e-5)


def test_members_start_from_the_one_run_weights_of_their_seed():
    config = SACConfig(hidden_sizes=(16, 16))
    stacked = StackedSACAgent(_agents(SACAgent, config, seeds=(4, 9)), config, "cpu")
    for k, seed in enumerate((4, 9)):
        alone = _agents(SACAgent, config, seeds=(seed,))[0]
        for (weight, bias), layer in zip(
            stacked.policy.trunk.member_linear(k),
            [m for m in alone.policy.trunk if isinstance(m, torch.nn.Linear)],
        ):
            assert torch.equal(weight, layer.weight) and torch.equal(bias, layer.bias)
        q1 = [m for m in alone.q1.net if isinstance(m, torch.nn.Linear)]
        for (weight, _), layer in zip(stacked.critics.member_linear(2 * k), q1):
            assert torch.equal(weight, layer.weight)


def test_a_member_comes_out_of_the_stack_as_its_one_run_policy():
    config = SACConfig(hidden_sizes=(16, 16))
    agents = _agents(SACAgent, config, seeds=(4, 9))
    stacked = StackedSACAgent(agents, config, "cpu")
    with torch.no_grad():  # train the stack a little, so that members differ from their start
        for weight in stacked.policy.trunk.weights:
            weight.add_(0.1 * torch.randn_like(weight))
    obs = np.random.default_rng(0).normal(size=(2, OBS)).astype(np.float32)
    state = torch.get_rng_state()
    for k in range(2):
        alone = stacked.policy.member_policy(k)
        assert set(alone.state_dict()) == set(agents[k].policy.state_dict())
        acted = alone.deterministic(torch.from_numpy(obs[k : k + 1]))[0].detach().numpy()
        np.testing.assert_allclose(acted, stacked.act_deterministic(obs)[k], atol=1e-6)
    assert torch.equal(torch.get_rng_state(), state)  # taking a member out draws nothing


def test_batched_guider_decides_and_acts_as_the_one_run_guider():
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    low, high = np.array([-1.0]), np.array([1.0])
    thresholds = (0.02, 0.05, 0.3)
    configs = [DRLEGConfig(hidden_sizes=(16, 16), guide_threshold=t) for t in thresholds]
    agent = StackedSACAgent(_mountaincar_agents(configs), configs[0], "cpu")
    explorer = StackedGuidedExplorer(agent, configs, demos, low, high, list(SEEDS))
    singles = [Guidance(c, demos, low, high, seed) for c, seed in zip(configs, SEEDS)]
    rng = np.random.default_rng(0)
    guided_total = 0
    for _ in range(300):
        # near the demonstrations and far from them, the same state for every member
        state = (
            demos.observations[rng.integers(len(demos.observations))] + rng.normal(0, 0.05, 2)
        ).astype(np.float32)
        obs = np.repeat(state[None], len(SEEDS), axis=0)
        guided, index = explorer.decide(obs, np.ones(len(SEEDS), dtype=bool))
        for k, single in enumerate(singles):
            expected = single.guide(state)
            assert guided[k] == (expected is not None)
            if expected is not None:  # same nearest demonstration, same noise stream
                ours = np.clip(
                    explorer.demo_actions[index[k]]
                    + configs[k].guide_noise_std * explorer.rngs[k].standard_normal(1),
                    low,
                    high,
                )
                assert np.allclose(ours, expected, atol=1e-6)
                guided_total += 1
    assert 0 < guided_total < 300 * len(SEEDS)  # both answers occurred


def _mountaincar_agents(configs):
    return [
        SACAgent(2, 1, np.array([-1.0]), np.array([1.0]), c, seed=s, cuda_graphs=False)
        for c, s in zip(configs, SEEDS)
    ]


def test_env_batch_steps_only_active_envs_and_restores_mid_episode():
    with EnvBatch("Hopper-v5", [3, 4], workers=1) as envs:
        obs = envs.reset(seeds=[3, 4])
        rng = np.random.default_rng(0)
        for _ in range(5):  # env 1 stands still: its rows come back empty
            obs[0] = envs.step(rng.uniform(-1, 1, (2, 3)), active=np.array([True, False])).obs[0]
        snapshot = envs.snapshot()
        assert len(snapshot[0]["actions"]) == 5 and len(snapshot[1]["actions"]) == 0
        later = envs.step(rng.uniform(-1, 1, (2, 3))).obs
    with EnvBatch("Hopper-v5", [3, 4], workers=0) as fresh:
        restored = fresh.restore(snapshot)
        assert np.array_equal(restored[0], obs[0]) and np.array_equal(restored[1], obs[1])
        assert not np.array_equal(later[0], restored[0])


def test_batched_evaluation_equals_one_run_evaluation():
    """Member k's episodes are those ``evaluate`` gives on its own env, whatever the
    episode lengths of the others."""

    def policy(obs):
        return np.tanh(obs[..., :1] * 3.0 + obs[..., 1:2] * 40.0).astype(np.float32)

    with EnvBatch(MOUNTAINCAR, [5, 6], workers=0) as envs:
        first = evaluate_members(envs, policy, 2, np.array([True, True]))
        second = evaluate_members(envs, policy, 2, np.array([True, True]))
    for k, seed in enumerate((5, 6)):
        env = make_env(MOUNTAINCAR, seed=seed)
        assert first[k] == evaluate(env, policy, 2)
        assert second[k] == evaluate(env, policy, 2)


def _specs(algo: str = "drl-eg", steps: int = 600, seeds=(0, 1), **hyper):
    hyper = {**TINY, **hyper}
    return [RunSpec(algo, MOUNTAINCAR, seed, steps, 200, 1, hyper) for seed in seeds]


def test_batch_lands_as_runs_under_the_one_run_addresses(tmp_path):
    members = [prepare(spec) for spec in _specs()]
    outcome = execute_batch(members, tmp_path, device="cpu")
    assert [r.path.name for r in outcome.runs] == [p.run_id for p in members]
    for run in outcome.runs:
        assert run.provenance["batch"]["size"] == 2
        assert run.provenance["batch"]["members"] == [p.run_id for p in members]
        assert list(run.curve["step"]) == [0, 200, 400, 600]
    assert not list(tmp_path.glob(".batch-*")) and not list(tmp_path.glob(".partial-*"))


def test_batched_curves_are_deterministic_and_independent_of_neighbours(tmp_path):
    """Same members, same curves; member 1 trained beside another seed than before ends on
    the same curve (V-SAC on CPU, batches of two or more)."""
    first = execute_batch(
        [prepare(s) for s in _specs(seeds=(0, 1))], tmp_path / "a", device="cpu"
    ).runs
    again = execute_batch(
        [prepare(s) for s in _specs(seeds=(0, 1))], tmp_path / "b", device="cpu"
    ).runs
    other = execute_batch(
        [prepare(s) for s in _specs(seeds=(5, 1))], tmp_path / "c", device="cpu"
    ).runs
    assert [r.curve["returns"].tolist() for r in first] == [
        r.curve["returns"].tolist() for r in again
    ]
    assert first[1].curve["returns"].tolist() == other[1].curve["returns"].tolist()


def test_a_diverging_member_fails_alone():
    members = [prepare(s) for s in _specs(algo="sac", seeds=(0, 1, 2))]
    failures = {}
    curves = {k: [] for k in range(3)}
    contexts = [
        TrainContext(MOUNTAINCAR, p.spec.seed, 600, 200, 1, on_eval=curves[k].append)
        for k, p in enumerate(members)
    ]
    original = StackedSACAgent._gradient_step

    def poisoned(self, batch, noise):
        losses = original(self, batch, noise)
        with torch.no_grad():  # member 1's critics turn NaN after every update
            for weight in self.critics.weights:
                weight[2:4] = float("nan")
        return losses

    StackedSACAgent._gradient_step = poisoned
    try:
        batched_trainer("sac")(
            BatchContext(contexts, on_member_failed=lambda k, why: failures.update({k: why})),
            [p.config for p in members],
        )
    finally:
        StackedSACAgent._gradient_step = original
    assert list(failures) == [1] and "diverged" in failures[1]
    assert curves[0][-1].step == 600 and curves[2][-1].step == 600
    assert all(np.isfinite(p.mean_return) for k in (0, 2) for p in curves[k])


def test_runner_reports_a_failed_member_and_keeps_the_others(tmp_path, monkeypatch):
    import baselines.batched as batched

    original = batched.StackedSACAgent._gradient_step

    def poisoned(self, batch, noise):
        losses = original(self, batch, noise)
        with torch.no_grad():
            for weight in self.critics.weights:
                weight[0:2] = float("nan")  # member 0
        return losses

    monkeypatch.setattr(batched.StackedSACAgent, "_gradient_step", poisoned)
    members = [prepare(s) for s in _specs(algo="sac", seeds=(0, 1))]
    outcome = execute_batch(members, tmp_path, device="cpu")
    assert [run_id for run_id, _ in outcome.failed] == [members[0].run_id]
    assert "diverged" in outcome.failed[0][1]
    assert not is_complete(members[0].directory(tmp_path))
    assert is_complete(members[1].directory(tmp_path))


KILL_SCRIPT = """
import sys
from pathlib import Path
from replicate.runner import execute_batch, prepare
from replicate.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY

if __name__ == "__main__":
    specs = [RunSpec("drl-eg", MOUNTAINCAR, s, 1600, 400, 1, dict(TINY)) for s in (0, 1)]
    execute_batch([prepare(s) for s in specs], Path(sys.argv[1]), device="cpu",
                  checkpoint_interval=300, env_workers=int(sys.argv[2]))
"""


@pytest.mark.slow
def test_kill_9_and_resume_a_batch_ends_on_the_uninterrupted_curves(tmp_path):
    script = tmp_path / "batch.py"
    script.write_text(KILL_SCRIPT)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "disable"}
    whole = tmp_path / "whole"
    subprocess.run(
        [sys.executable, str(script), str(whole), "0"], check=True, env=env, cwd=ROOT, timeout=300
    )
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, str(script), str(killed), "1"], env=env, cwd=ROOT)
    deadline = time.time() + 240
    while time.time() < deadline:  # wait for a checkpoint taken mid-run
        found = list(killed.glob(".batch-*/checkpoint.pt"))
        if found and torch.load(found[0], weights_only=False)["step"] >= 600:
            break
        time.sleep(0.2)
    else:
        pytest.fail("no checkpoint appeared")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not list(killed.glob("drl-eg*"))  # nothing complete yet
    subprocess.run(
        [sys.executable, str(script), str(killed), "1"], check=True, env=env, cwd=ROOT, timeout=300
    )
    for name in sorted(p.name for p in whole.iterdir() if not p.name.startswith(".")):
        a = (whole / name / "curve.csv").read_text().splitlines()
        b = (killed / name / "curve.csv").read_text().splitlines()

        def strip(lines):
            return [line.rsplit(",", 1)[0] for line in lines]  # wall time differs

        assert strip(a) == strip(b)
        parts = json.loads((killed / name / "sittings.json").read_text())
        assert len(parts) == 2 and parts[1]["resumed_from_step"] >= 600


def test_grid_batch_errors_are_one_line_and_write_nothing(tmp_path):
    store = tmp_path / "store"
    base = [
        sys.executable,
        "-m",
        "replicate",
        "fig3",
        "--profile",
        "smoke",
        "--store",
        str(store),
        "--out",
        str(tmp_path / "report"),
    ]
    env = {**os.environ, "MUJOCO_GL": "disable"}
    for extra, needle in ((["--batch", "0"], "batch size must be >= 1"),):
        result = subprocess.run(base + extra, capture_output=True, text=True, env=env, cwd=ROOT)
        assert result.returncode == 2
        assert needle in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert not store.exists() or not any(store.iterdir())
    from replicate.errors import HarnessError
    from replicate.experiments import resolve_batch

    ppo_only = [prepare(RunSpec("ppo", MOUNTAINCAR, 0, 400, 200, 1, {}))]
    with pytest.raises(HarnessError, match="no batched trainer for ppo"):
        resolve_batch(4, ppo_only, "cpu")


def test_plan_batches_groups_by_everything_but_the_seed_and_t2():
    from replicate.experiments import plan_batches

    specs = (
        _specs(seeds=(0, 1, 2))
        + _specs(algo="sac", seeds=(0, 1))
        + [RunSpec("ppo", MOUNTAINCAR, 0, 600, 200, 1, {})]
        + _specs(seeds=(0,), guide_threshold=0.2, guide_noise_std=0.3)
        + _specs(seeds=(0,), learning_rate=1e-3)
    )
    tasks = plan_batches([prepare(s) for s in specs], batch=2)
    shapes = sorted(
        (t[0].spec.algo, len(t)) if isinstance(t, list) else (t.spec.algo, 0) for t in tasks
    )
    # T2 and sigma are per member: the 0.2 point joins seed 2 of the default point; another
    # learning rate is another batch
    assert shapes == [("drl-eg", 1), ("drl-eg", 2), ("drl-eg", 2), ("ppo", 0), ("sac", 2)]
    mixed = next(
        t for t in tasks if isinstance(t, list) and len({p.config.guide_threshold for p in t}) == 2
    )
    assert [p.spec.seed for p in mixed] == [2, 0]
    assert not any(isinstance(t, list) for t in plan_batches([prepare(s) for s in specs], None))


def test_a_t2_sweep_in_one_batch_gives_each_point_its_own_curve(tmp_path):
    """Members that differ in T2 and sigma (the same seed included) train as one batch on
    CPU and end on the curves their own points give in batches of their own."""
    points = [
        {"guide_threshold": 0.02, "guide_noise_std": 0.1},
        {"guide_threshold": 0.3, "guide_noise_std": 0.3},
    ]
    mixed = execute_batch(
        [prepare(s) for point in points for s in _specs(seeds=(0,), **point)],
        tmp_path / "mixed",
        device="cpu",
    ).runs
    alone = [
        execute_batch(
            [prepare(s) for s in _specs(seeds=(0, 1), **point)],
            tmp_path / f"alone{i}",
            device="cpu",
        ).runs[0]
        for i, point in enumerate(points)
    ]
    assert [r.path.name for r in mixed] == [r.path.name for r in alone]
    assert [r.curve["returns"].tolist() for r in mixed] == [
        r.curve["returns"].tolist() for r in alone
    ]
    guided = [r.curve["guided_fraction"].iloc[1:].mean() for r in mixed]
    assert guided[0] < guided[1]  # each member kept its own T2


def test_every_batched_algorithm_trains_a_tiny_batch():
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    for algo in ("sac", "sac-twin-q", "drl-eg", "drl-eg-gmm", "drl-eg-twin-q"):
        algorithm = get_algorithm(algo)
        known = set(algorithm.config_cls.__dataclass_fields__)
        config = algorithm.make_config({k: v for k, v in TINY.items() if k in known})
        points = {0: [], 1: []}
        contexts = [
            TrainContext(MOUNTAINCAR, s, 300, 150, 1, demos=demos, on_eval=points[s].append)
            for s in (0, 1)
        ]
        batched_trainer(algo)(BatchContext(contexts), [config, config])
        assert [p.step for p in points[0]] == [0, 150, 300], algo
        assert curve_signature(points[0]) != curve_signature(points[1]), algo


def test_a_member_failed_before_a_checkpoint_stays_failed_on_resume(tmp_path):
    members = [prepare(s) for s in _specs(algo="sac", seeds=(0, 1), steps=800)]
    original = StackedSACAgent._gradient_step

    def poisoned(self, batch, noise):
        losses = original(self, batch, noise)
        with torch.no_grad():
            for weight in self.critics.weights:
                weight[0:2] = float("nan")
        return losses

    class Interrupted(Exception):
        pass

    def run(poison: bool, stop_at: int | None) -> dict[int, str]:
        failures: dict[int, str] = {}
        seen = [0]

        def on_steps(n: int) -> None:
            seen[0] += 1
            if stop_at is not None and seen[0] == stop_at:
                raise Interrupted

        contexts = [TrainContext(MOUNTAINCAR, p.spec.seed, 800, 200, 1) for p in members]
        bctx = BatchContext(
            contexts,
            on_steps=on_steps,
            checkpoint_interval=100,
            checkpoint_path=tmp_path / "checkpoint.pt",
            on_member_failed=lambda k, why: failures.update({k: why}),
        )
        StackedSACAgent._gradient_step = poisoned if poison else original
        try:
            batched_trainer("sac")(bctx, [p.config for p in members])
        except Interrupted:
            pass
        finally:
            StackedSACAgent._gradient_step = original
        return failures

    assert list(run(poison=True, stop_at=450)) == [0]  # failed, then interrupted
    resumed = run(poison=False, stop_at=None)
    assert list(resumed) == [0] and "diverged" in resumed[0]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_batch_trains_on_the_gpu_with_graphs(tmp_path):
    """Run on a GPU machine by benchmarks/gpu_checks.py too (reports/bench/batched_gpu.json)."""
    members = [prepare(s) for s in _specs(algo="sac-twin-q", steps=600, seeds=(0, 1))]
    outcome = execute_batch(members, tmp_path, device="cuda")
    assert not outcome.failed and len(outcome.runs) == 2
    assert all(r.provenance["batch"]["device"].startswith("cuda") for r in outcome.runs)


def test_a_batch_records_the_training_returns_of_the_one_run_path(tmp_path):
    """Before learning starts each member acts as its seed's one run does, so the training
    episodes' returns on its curve are the one run's (Hopper: short untrained episodes)."""
    hyper = {**TINY, "learning_starts": 1_000}
    specs = [RunSpec("sac", "Hopper-v5", seed, 400, 200, 1, hyper) for seed in (0, 1)]
    runs = execute_batch([prepare(s) for s in specs], tmp_path, device="cpu").runs
    for seed, run in zip((0, 1), runs):
        points, _ = train_tiny(
            "sac", seed=seed, steps=400, env_id="Hopper-v5", learning_starts=1_000
        )
        one_run = [p.train_return for p in points]
        assert np.isnan(one_run[0]) and np.isfinite(one_run[1:]).all()
        np.testing.assert_allclose(run.curve["train_return"], one_run, rtol=1e-5)


@pytest.mark.parametrize("twin_q", [False, True])
def test_a_members_update_is_the_same_in_a_stack_of_2_or_of_8(twin_q):
    """Bitwise, weights and Adam moments, also after a checkpoint round trip: on the CPU
    neither the products nor Adam may round a member's numbers by how many members are
    stacked (the fused Adam's scalar tail did, on AVX2)."""
    config = (TwinQSACConfig if twin_q else SACConfig)(hidden_sizes=(32, 32), batch_size=ROWS)
    agent_cls, stack_cls = (
        (TwinQSACAgent, StackedTwinQAgent) if twin_q else (SACAgent, StackedSACAgent)
    )

    def stack(seeds):  # the policy's output bias: 2 * ACT floats per member, short of a vector
        return stack_cls(_agents(agent_cls, config, seeds), config, "cpu")

    small, large = stack((0, 1)), stack((0, 1) * 4)
    generator = torch.Generator().manual_seed(7)
    for step in range(5):
        if step == 3:  # resume the large stack from its own checkpoint
            resumed = stack((0, 1) * 4)
            load_agent_state(resumed, agent_state(large))
            large = resumed
        batch = Batch(
            torch.randn(2, ROWS, OBS, generator=generator),
            torch.rand(2, ROWS, ACT, generator=generator) * 2 - 1,
            torch.randn(2, ROWS, generator=generator),
            torch.randn(2, ROWS, OBS, generator=generator),
            (torch.rand(2, ROWS, generator=generator) < 0.2).float(),
        )
        noises = [torch.randn(2, ROWS, ACT, generator=generator) for _ in range(2 if twin_q else 1)]
        repeated = Batch(*[t.repeat(4, *[1] * (t.dim() - 1)) for t in vars(batch).values()])
        if twin_q:
            small._gradient_step(batch, tuple(noises))
            large._gradient_step(repeated, tuple(n.repeat(4, 1, 1) for n in noises))
        else:
            small._gradient_step(batch, noises[0])
            large._gradient_step(repeated, noises[0].repeat(4, 1, 1))
    if twin_q:
        assert torch.equal(small.log_alpha, large.log_alpha[:2])
    for name in small.MODULES:
        one, many = getattr(small, name), getattr(large, name)
        if isinstance(one, torch.optim.Optimizer):
            for p, q in zip(
                [p for g in one.param_groups for p in g["params"]],
                [q for g in many.param_groups for q in g["params"]],
            ):
                for moment in ("exp_avg", "exp_avg_sq"):
                    assert torch.equal(one.state[p][moment], many.state[q][moment][: p.shape[0]]), (
                        name
                    )
        else:  # members first; the critics stack two per member
            for p, q in zip(one.parameters(), many.parameters()):
                assert torch.equal(p, q[: p.shape[0]]), name


def test_a_batch_checkpoint_from_before_the_two_adam_groups_says_how_to_start_over():
    config = SACConfig(hidden_sizes=(16, 16))
    stacked = StackedSACAgent(_agents(SACAgent, config, seeds=(0, 1)), config, "cpu")
    state = agent_state(stacked)
    state["v_optimizer"] = torch.optim.Adam(stacked.v.parameters(), fused=True).state_dict()
    with pytest.raises(ValueError, match=r"predates .* delete the batch's checkpoint"):
        load_agent_state(stacked, state)
