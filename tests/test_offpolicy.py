"""The off-policy trainer of the SAC family (``baselines.offpolicy``): N members with a
leading member axis, a single run being N = 1. Member k trains as the batch of one of its
seed does (to rounding; between batches of two or more, bit for bit): its initial weights,
updates, guidance, evaluation, curve, failure and resume are its own, whatever members
share its batch."""

from __future__ import annotations

import copy
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

from baselines.common.buffer import Batch
from baselines.common.context import BatchContext, TrainContext
from baselines.common.evaluation import evaluate
from baselines.common.networks import TanhGaussianPolicy
from baselines.contract import agent_state, load_agent_state
from baselines.drl_eg import DRLEGConfig, GuidedExplorer, functional_discriminator, nearest_demo
from baselines.registry import batched_trainer
from baselines.sac import SACAgent, SACConfig, SACNetworks
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from baselines.training_loop import evaluate_members
from envs import make_env
from envs.vector import EnvBatch
from replicate.demos import default_demo_path, load_demos
from replicate.store.runner import execute_batch, is_complete, prepare
from replicate.store.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY, assert_members_agree, train_tiny

HOPPER, OBS, ACT, ROWS, SEEDS = "Hopper-v5", 11, 3, 32, (0, 1, 2)
ROOT = Path(__file__).resolve().parents[1]
# each agent's stacked modules and how many stacked rows a member has in each
MODULES = {
    SACAgent: (("policy", 1), ("critics", 2), ("v", 1), ("v_target", 1)),
    TwinQSACAgent: (("policy", 1), ("critics", 2), ("critics_target", 2)),
}


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Agents updated here directly run on one thread, as training sets it (torch_threads)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _agent(agent_cls, config, seeds):
    return agent_cls(list(seeds), HOPPER, config, cuda_graphs=False)


def _config(agent_cls, **overrides):
    config_cls = TwinQSACConfig if agent_cls is TwinQSACAgent else SACConfig
    return config_cls(**{"hidden_sizes": (32, 32), "batch_size": ROWS, **overrides})


def _minibatches(generator: torch.Generator, n: int = len(SEEDS)) -> Batch:
    return Batch(
        torch.randn(n, ROWS, OBS, generator=generator),
        torch.rand(n, ROWS, ACT, generator=generator) * 2 - 1,
        torch.randn(n, ROWS, generator=generator),
        torch.randn(n, ROWS, OBS, generator=generator),
        (torch.rand(n, ROWS, generator=generator) < 0.2).float(),
    )


def _member(batch: Batch, k: int) -> Batch:
    """Member k's rows as the minibatch of a batch of one."""
    return Batch(*[t[k : k + 1] for t in vars(batch).values()])


@pytest.mark.parametrize("agent_cls", [SACAgent, TwinQSACAgent])
def test_a_batched_gradient_step_equals_each_members_step_alone(agent_cls):
    """Three gradient steps of a batch of 3 on given minibatches and noise against the
    batches of one of the same seeds on each member's slice of the same numbers: losses
    and then weights (policy, critics, V or target critics, temperature) within 1e-5."""
    twin_q = agent_cls is TwinQSACAgent
    config = _config(agent_cls)
    batch = _agent(agent_cls, config, SEEDS)
    alone = [_agent(agent_cls, config, [s]) for s in SEEDS]
    generator = torch.Generator().manual_seed(7)
    for _ in range(3):
        minibatch = _minibatches(generator)
        noises = [
            torch.randn(len(SEEDS), ROWS, ACT, generator=generator)
            for _ in range(2 if twin_q else 1)
        ]
        losses = batch.gradient_step(minibatch, tuple(noises) if twin_q else noises[0])
        for k, agent in enumerate(alone):
            mine = [noise[k : k + 1] for noise in noises]
            reference = agent.gradient_step(
                _member(minibatch, k), tuple(mine) if twin_q else mine[0]
            )
            assert set(losses) == set(reference)
            for name, value in reference.items():
                assert float(losses[name][k]) == pytest.approx(
                    float(value[0]), abs=1e-5, rel=1e-5
                ), name
    for name, per_member in MODULES[agent_cls]:
        assert_members_agree(batch, alone, name, per_member)


@pytest.mark.parametrize("agent_cls", [SACAgent, TwinQSACAgent])
def test_a_member_starts_from_the_weights_of_its_seed(agent_cls):
    """Member 1 of the batch of seeds (4, 9) is, weight for weight, the batch of one of
    seed 9: its seed alone draws its networks."""
    config = _config(agent_cls, hidden_sizes=(16, 16))
    batch = _agent(agent_cls, config, (4, 9))
    alone = _agent(agent_cls, config, (9,))
    for name, per_member in MODULES[agent_cls]:
        stacked = list(getattr(batch, name).parameters())
        own = list(getattr(alone, name).parameters())
        assert len(stacked) == len(own)
        for value, reference in zip(stacked, own):
            assert torch.equal(value[per_member : 2 * per_member], reference), name
    if agent_cls is TwinQSACAgent:
        assert torch.equal(batch.log_alpha[1:], alone.log_alpha)


def test_a_member_taken_out_of_the_stack_acts_as_the_stack_does():
    """``member_policy(k)`` is a plain tanh-Gaussian policy (what an expert file holds)
    whose deterministic and sampled actions are member k's in the stack; taking it out
    draws no random numbers."""
    config = SACConfig(hidden_sizes=(16, 16))
    batch = _agent(SACAgent, config, (4, 9))
    low, high = -np.ones(ACT), np.ones(ACT)
    plain = SACNetworks.initial(0, OBS, ACT, low, high, config).policy.state_dict()
    with torch.no_grad():  # move the members away from their initial weights
        for weight in batch.policy.trunk.weights:
            weight.add_(0.1 * torch.randn_like(weight))
    obs = torch.from_numpy(np.random.default_rng(0).normal(size=(2, OBS)).astype(np.float32))
    noise = torch.randn(2, 1, ACT)
    sampled, log_prob = batch.policy.sample(obs[:, None, :], noise=noise)
    state = torch.get_rng_state()
    for k in range(2):
        alone = batch.policy.member_policy(k)
        assert type(alone) is TanhGaussianPolicy and set(alone.state_dict()) == set(plain)
        acted = alone.deterministic(obs[k : k + 1])[0].detach().numpy()
        np.testing.assert_allclose(acted, batch.act_deterministic(obs.numpy())[k], atol=1e-6)
        action, density = alone.sample(obs[k : k + 1], noise=noise[k])
        torch.testing.assert_close(action, sampled[k], atol=1e-6, rtol=1e-6)
        torch.testing.assert_close(density, log_prob[k], atol=1e-5, rtol=1e-5)
    assert torch.equal(torch.get_rng_state(), state)


def test_the_batched_guider_decides_and_acts_as_one_state_at_a_time():
    """N different states at once, each member with its own T2, sigma and gate: D(s) is
    eq. 11 by brute force (``nearest_demo``, ``functional_discriminator``) state by state;
    a guided member takes the nearest demonstration's action plus sigma times a draw of its
    own stream, clipped, and its policy's noise stream stays still; an unguided member
    takes its policy's sample."""
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    low, high = np.array([-1.0]), np.array([1.0])
    points = ((0.02, 0.1), (0.05, 0.5), (0.3, 0.3))
    configs = [
        DRLEGConfig(hidden_sizes=(16, 16), guide_threshold=t, guide_noise_std=s) for t, s in points
    ]
    agent = SACAgent(list(SEEDS), MOUNTAINCAR, configs[0], cuda_graphs=False)
    explorer = GuidedExplorer(agent, configs, demos, low, high, list(SEEDS))
    states = np.asarray(demos.observations, dtype=np.float64)
    draws = copy.deepcopy(explorer.rngs)  # each member's guider stream, followed alongside
    rng = np.random.default_rng(0)
    counts = {True: 0, False: 0}
    for _ in range(200):
        # each member its own state, near the demonstrations or far from them
        obs = (
            states[rng.integers(len(states), size=len(SEEDS))] + rng.normal(0, 0.05, (3, 2))
        ).astype(np.float32)
        gate = rng.random(len(SEEDS)) < 0.8  # a closed gate (R_demo <= R_pi) never guides
        explorer.policy_returns = np.where(gate, -np.inf, np.inf)
        guided, index = explorer.decide(obs, gate)
        noise_states = [g.get_state() for g in agent.generators]
        actions, chosen = explorer.choose(obs)
        assert np.array_equal(chosen, guided)
        for k, config in enumerate(configs):
            distance, nearest = nearest_demo(states, obs[k].astype(np.float64))
            expected = bool(gate[k]) and functional_discriminator(distance, config.guide_threshold)
            assert guided[k] == expected
            counts[expected] += 1
            if expected:
                assert np.array_equal(states[index[k]], states[nearest])
                action = np.clip(
                    demos.actions[nearest] + config.guide_noise_std * draws[k].standard_normal(1),
                    low,
                    high,
                )
                np.testing.assert_allclose(actions[k], action, atol=1e-6)
                assert torch.equal(agent.generators[k].get_state(), noise_states[k])
            else:
                assert index[k] == -1
                stream = torch.Generator().set_state(noise_states[k])
                noise = torch.randn((1, agent.act_dim), generator=stream)
                action, _ = agent.policy.member_policy(k).sample(
                    torch.from_numpy(obs[k : k + 1]), noise=noise
                )
                np.testing.assert_allclose(actions[k], action[0].detach().numpy(), atol=1e-6)
    assert counts[True] > 20 and counts[False] > 20  # both answers occurred


def test_env_batch_steps_only_active_envs_and_restores_mid_episode():
    with EnvBatch(HOPPER, [3, 4], workers=1) as envs:
        obs = envs.reset(seeds=[3, 4])
        rng = np.random.default_rng(0)
        for _ in range(5):  # env 1 stands still: its rows come back empty
            obs[0] = envs.step(rng.uniform(-1, 1, (2, 3)), active=np.array([True, False])).obs[0]
        snapshot = envs.snapshot()
        assert len(snapshot[0]["actions"]) == 5 and len(snapshot[1]["actions"]) == 0
        later = envs.step(rng.uniform(-1, 1, (2, 3))).obs
    with EnvBatch(HOPPER, [3, 4], workers=0) as fresh:
        restored = fresh.restore(snapshot)
        assert np.array_equal(restored[0], obs[0]) and np.array_equal(restored[1], obs[1])
        assert not np.array_equal(later[0], restored[0])


def test_each_members_evaluation_is_that_of_its_own_env():
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


def test_batch_lands_as_runs_under_their_run_addresses(tmp_path):
    members = [prepare(spec) for spec in _specs()]
    outcome = execute_batch(members, tmp_path, device="cpu")
    assert [r.path.name for r in outcome.runs] == [p.run_id for p in members]
    for run in outcome.runs:
        assert run.provenance["batch"]["size"] == 2
        assert run.provenance["batch"]["members"] == [p.run_id for p in members]
        assert run.provenance["trainer"] == "baselines.offpolicy.run_off_policy"
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


def _poison(monkeypatch, rows: slice) -> None:
    """After every update, the critics of the member at critic rows ``rows`` turn NaN."""
    original = SACAgent.gradient_step

    def poisoned(self, batch, noise, kind):
        losses = original(self, batch, noise, kind)
        with torch.no_grad():
            for weight in self.critics.weights:
                weight[rows] = float("nan")
        return losses

    monkeypatch.setattr("baselines.sac.SACAgent.gradient_step", poisoned)


def test_a_diverging_member_fails_alone(monkeypatch):
    members = [prepare(s) for s in _specs(algo="sac", seeds=(0, 1, 2))]
    failures = {}
    curves = {k: [] for k in range(3)}
    contexts = [
        TrainContext(MOUNTAINCAR, p.spec.seed, 600, 200, 1, on_eval=curves[k].append)
        for k, p in enumerate(members)
    ]
    _poison(monkeypatch, slice(2, 4))  # member 1
    batched_trainer("sac")(
        BatchContext(contexts, on_member_failed=lambda k, why: failures.update({k: why})),
        [p.config for p in members],
    )
    assert list(failures) == [1] and "diverged" in failures[1]
    assert curves[0][-1].step == 600 and curves[2][-1].step == 600
    assert all(np.isfinite(p.mean_return) for k in (0, 2) for p in curves[k])


def test_runner_reports_a_failed_member_and_keeps_the_others(tmp_path, monkeypatch):
    _poison(monkeypatch, slice(0, 2))  # member 0
    members = [prepare(s) for s in _specs(algo="sac", seeds=(0, 1))]
    outcome = execute_batch(members, tmp_path, device="cpu")
    assert [run_id for run_id, _ in outcome.failed] == [members[0].run_id]
    assert "diverged" in outcome.failed[0][1]
    assert not is_complete(members[0].directory(tmp_path))
    assert is_complete(members[1].directory(tmp_path))


KILL_SCRIPT = """
import sys
from pathlib import Path
from replicate.store.runner import execute, execute_batch, prepare
from replicate.store.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY

if __name__ == "__main__":
    store, workers = Path(sys.argv[1]), int(sys.argv[2])
    seeds = [int(s) for s in sys.argv[3].split(",")]
    members = [prepare(RunSpec("drl-eg", MOUNTAINCAR, s, 1600, 400, 1, dict(TINY))) for s in seeds]
    if len(members) == 1:  # a single run: runner.execute, a batch of one
        execute(members[0], store, device="cpu", checkpoint_interval=300)
    else:
        execute_batch(members, store, device="cpu", checkpoint_interval=300, env_workers=workers)
"""


@pytest.mark.slow
@pytest.mark.parametrize("seeds", ["0,1", "0"], ids=["batch", "single-run"])
def test_kill_9_and_resume_ends_on_the_uninterrupted_curves(tmp_path, seeds):
    """A batch (its envs stepped by a worker process the second time) and a single run
    through ``runner.execute``: killed with SIGKILL after a checkpoint, then started again,
    they end on the curves of an uninterrupted training."""
    script = tmp_path / "train.py"
    script.write_text(KILL_SCRIPT)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "disable"}

    def command(store: Path, workers: str) -> list[str]:
        return [sys.executable, str(script), str(store), workers, seeds]

    whole = tmp_path / "whole"
    subprocess.run(command(whole, "0"), check=True, env=env, cwd=ROOT, timeout=300)
    killed = tmp_path / "killed"
    proc = subprocess.Popen(command(killed, "1"), env=env, cwd=ROOT)
    deadline = time.time() + 240
    while time.time() < deadline:  # wait for a checkpoint taken mid-run
        found = list(killed.glob(".batch-*/checkpoint.pt"))
        try:
            if found and torch.load(found[0], weights_only=False)["step"] >= 600:
                break
        except (EOFError, RuntimeError):  # caught while it was being written
            pass
        time.sleep(0.2)
    else:
        pytest.fail("no checkpoint appeared")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not list(killed.glob("drl-eg*"))  # nothing complete yet
    subprocess.run(command(killed, "1"), check=True, env=env, cwd=ROOT, timeout=300)
    names = sorted(p.name for p in whole.iterdir() if not p.name.startswith("."))
    assert len(names) == len(seeds.split(","))
    for name in names:
        a = (whole / name / "curve.csv").read_text().splitlines()
        b = (killed / name / "curve.csv").read_text().splitlines()

        def strip(lines):
            return [line.rsplit(",", 1)[0] for line in lines]  # wall time differs

        assert strip(a) == strip(b)
        parts = json.loads((killed / name / "segments.json").read_text())
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
    from replicate.grids.planning import resolve_batch

    ppo_only = [prepare(RunSpec("ppo", MOUNTAINCAR, 0, 400, 200, 1, {}))]
    with pytest.raises(HarnessError, match="no batched trainer for ppo"):
        resolve_batch(4, ppo_only, "cpu")


def test_plan_batches_groups_by_everything_but_the_seed_and_t2():
    from replicate.grids.planning import plan_batches

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


def test_a_member_failed_before_a_checkpoint_stays_failed_on_resume(tmp_path, monkeypatch):
    members = [prepare(s) for s in _specs(algo="sac", seeds=(0, 1), steps=800)]

    class Interrupted(Exception):
        pass

    def run(stop_at: int | None) -> dict[int, str]:
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
        try:
            batched_trainer("sac")(bctx, [p.config for p in members])
        except Interrupted:
            pass
        return failures

    _poison(monkeypatch, slice(0, 2))  # member 0
    assert list(run(stop_at=450)) == [0]  # failed, then interrupted
    monkeypatch.undo()
    resumed = run(stop_at=None)
    assert list(resumed) == [0] and "diverged" in resumed[0]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_a_batch_trains_on_the_gpu_with_graphs(tmp_path):
    """Run on a GPU machine by benchmarks/gpu_checks.py too (reports/bench/batched_gpu.json)."""
    members = [prepare(s) for s in _specs(algo="sac-twin-q", steps=600, seeds=(0, 1))]
    outcome = execute_batch(members, tmp_path, device="cuda")
    assert not outcome.failed and len(outcome.runs) == 2
    assert all(r.provenance["batch"]["device"].startswith("cuda") for r in outcome.runs)


def test_a_member_records_the_training_returns_of_its_seed_alone(tmp_path):
    """Before learning starts each member acts as its seed's batch of one does, so the
    training episodes' returns on its curve are those of its seed alone (Hopper: short
    untrained episodes)."""
    hyper = {**TINY, "learning_starts": 1_000}
    specs = [RunSpec("sac", HOPPER, seed, 400, 200, 1, hyper) for seed in (0, 1)]
    runs = execute_batch([prepare(s) for s in specs], tmp_path, device="cpu").runs
    for seed, run in zip((0, 1), runs):
        points, _ = train_tiny("sac", seed=seed, steps=400, env_id=HOPPER, learning_starts=1_000)
        alone = [p.train_return for p in points]
        assert np.isnan(alone[0]) and np.isfinite(alone[1:]).all()
        np.testing.assert_allclose(run.curve["train_return"], alone, rtol=1e-5)


@pytest.mark.parametrize("agent_cls", [SACAgent, TwinQSACAgent])
def test_a_members_update_is_the_same_in_a_stack_of_2_or_of_8(agent_cls):
    """Bitwise, weights and Adam moments, also after a checkpoint round trip: on the CPU
    neither the products nor Adam may round a member's numbers by how many members are
    stacked (the fused Adam's scalar tail did, on AVX2)."""
    twin_q = agent_cls is TwinQSACAgent
    config = _config(agent_cls)

    def stack(seeds):  # the policy's output bias: 2 * ACT floats per member, short of a vector
        return _agent(agent_cls, config, seeds)

    small, large = stack((0, 1)), stack((0, 1) * 4)
    generator = torch.Generator().manual_seed(7)
    for step in range(5):
        if step == 3:  # resume the large stack from its own checkpoint
            resumed = stack((0, 1) * 4)
            load_agent_state(resumed, agent_state(large))
            large = resumed
        batch = _minibatches(generator, n=2)
        noises = [torch.randn(2, ROWS, ACT, generator=generator) for _ in range(2 if twin_q else 1)]
        repeated = Batch(*[t.repeat(4, *[1] * (t.dim() - 1)) for t in vars(batch).values()])
        if twin_q:
            small.gradient_step(batch, tuple(noises))
            large.gradient_step(repeated, tuple(n.repeat(4, 1, 1) for n in noises))
        else:
            small.gradient_step(batch, noises[0])
            large.gradient_step(repeated, noises[0].repeat(4, 1, 1))
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
    batch = _agent(SACAgent, SACConfig(hidden_sizes=(16, 16)), (0, 1))
    state = agent_state(batch)
    state["v_optimizer"] = torch.optim.Adam(batch.v.parameters(), fused=True).state_dict()
    with pytest.raises(ValueError, match=r"predates .* delete the batch's checkpoint"):
        load_agent_state(batch, state)


def test_a_member_diverging_between_looks_at_its_losses_fails_alone(tmp_path, monkeypatch):
    """On a GPU the losses are read every 100 steps; a member whose networks turned NaN in
    between must not pass its NaN state to the DRL-EG batch's shared KD-tree lookup (which
    would fail the whole batch and discard every member's work)."""
    monkeypatch.setattr(
        "baselines.training_loop.losses_due", lambda device, step, total: step == total
    )
    original = SACAgent.gradient_step

    def poisoned(self, batch, noise, kind):
        losses = original(self, batch, noise, kind)
        with torch.no_grad():
            for weight in self.policy.parameters():
                weight[1] = float("nan")  # member 1's slice of the stacked policy
        return losses

    monkeypatch.setattr("baselines.sac.SACAgent.gradient_step", poisoned)
    members = [prepare(s) for s in _specs(algo="drl-eg", seeds=(0, 1, 2), guide_threshold=1.0)]
    outcome = execute_batch(members, tmp_path, device="cpu")
    assert [run_id for run_id, _ in outcome.failed] == [members[1].run_id]
    assert "non-finite action" in outcome.failed[0][1]
    assert all(is_complete(members[k].directory(tmp_path)) for k in (0, 2))
