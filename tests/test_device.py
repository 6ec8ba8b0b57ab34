"""Device choice, the CUDA-graph update, and checkpoints that cross devices.

The tests marked ``cuda`` run only where torch sees a GPU (never in CI); the rest check on
CPU what a user without a GPU meets.
"""

import dataclasses
import json

import numpy as np
import pytest
import torch

from baselines.common.checkpoint import save_checkpoint
from baselines.common.device import DeviceUnavailableError, resolve_device, worker_devices
from baselines.common.stacked import StackedReplay
from baselines.sac import SACAgent, SACConfig
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from replicate.cli.main import main
from replicate.errors import HarnessError
from replicate.store.runner import (
    CHECKPOINT_FILE,
    CURVE_COLUMNS,
    batch_id,
    execute,
    partial_directory,
    prepare,
)
from replicate.store.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


@pytest.mark.parametrize(
    "gpu_present, requested, has_gpu_path, expected",
    [
        (False, "auto", True, "cpu"),
        (True, "auto", True, "cuda"),
        (True, "auto", False, "cpu"),  # PPO and DDPGfD stay on CPU
        (True, "cuda", False, "cpu"),
        (True, "cpu", True, "cpu"),
        (True, "cuda", True, "cuda"),
    ],
)
def test_device_resolution(monkeypatch, gpu_present, requested, has_gpu_path, expected):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: gpu_present)
    assert resolve_device(requested, has_gpu_path) == expected


def test_asking_for_cuda_without_a_gpu_fails_and_names_the_way_out(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(DeviceUnavailableError):
        resolve_device("cuda", True)
    with pytest.raises(ValueError, match="unknown device"):
        resolve_device("tpu", True)
    store = tmp_path / "store"
    code = main(
        [
            "train",
            "--algo",
            "sac",
            "--env",
            MOUNTAINCAR,
            "--steps",
            "10",
            "--device",
            "cuda",
            "--store",
            str(store),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "no CUDA GPU" in err and "--device cpu" in err
    assert not store.exists() or not any(store.iterdir())


def test_provenance_names_the_device(tmp_path):
    spec = RunSpec("sac", MOUNTAINCAR, 0, 120, 60, 1, dict(TINY))
    run = execute(prepare(spec), tmp_path, device="cpu")
    assert run.provenance["device"] == "cpu"


def test_the_training_loop_refuses_a_checkpoint_of_the_other_device(tmp_path):
    from baselines.common.checkpoint import CheckpointDeviceError
    from baselines.common.context import TrainContext
    from baselines.registry import get_algorithm

    checkpoint = tmp_path / "checkpoint.pt"
    save_checkpoint(checkpoint, {"step": 200, "device": "cuda"})
    algorithm = get_algorithm("sac")
    ctx = TrainContext(
        env_id=MOUNTAINCAR,
        seed=0,
        total_steps=400,
        eval_interval=100,
        eval_episodes=1,
        checkpoint_path=checkpoint,
        checkpoint_interval=100,
    )
    with pytest.raises(CheckpointDeviceError, match="made on cuda"):
        algorithm.train(ctx, algorithm.make_config(dict(TINY)))


def _agents(kind: str, device: str):
    """Two agents of seeds 0 and 1: one replays its update as a CUDA graph, one runs it
    eagerly, on the same replay."""
    agent_cls, config = (
        (SACAgent, SACConfig()) if kind == "sac" else (TwinQSACAgent, TwinQSACConfig())
    )

    def make(graphs: bool):
        agent = agent_cls([0, 1], "Hopper-v5", config, device=device, cuda_graphs=graphs)
        agent.buffer = _filled_replay(device)
        return agent

    return make(True), make(False)


def _filled_replay(device: str) -> StackedReplay:
    rng = np.random.default_rng(0)
    replay = StackedReplay(2, 11, 3, 2000, torch.device(device))
    for _ in range(2000):
        replay.add(
            rng.normal(size=(2, 11)),
            rng.uniform(-1, 1, (2, 3)),
            rng.normal(size=2),
            rng.normal(size=(2, 11)),
            (rng.random(2) < 0.05).astype(np.float32),
        )
    return replay


@cuda
@pytest.mark.parametrize("kind", ["sac", "sac-twin-q"])
def test_graphed_updates_follow_the_eager_ones(kind):
    """The graphed step draws its indices and noise on the device, the eager one too when
    given the same device stream: both start from one seed of it."""
    graphed, eager = _agents(kind, "cuda")
    for _ in range(12):  # warm-up, capture, then replays
        torch.cuda.manual_seed(len(graphed.buffer.data))
        graphed._size.fill_(graphed.buffer.size)
        got = graphed._update_graph(size=graphed._size)
        torch.cuda.manual_seed(len(eager.buffer.data))
        eager._size.fill_(eager.buffer.size)
        want = eager._update_graph(size=eager._size)
        for name in want:
            assert torch.allclose(got[name], want[name], rtol=1e-4, atol=1e-5), name
    for a, b in zip(graphed.policy.parameters(), eager.policy.parameters(), strict=True):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-5)
    assert graphed._update_graph.graph is not None and eager._update_graph.graph is None


@cuda
def test_runs_train_on_the_gpu_and_say_so(tmp_path):
    sac = execute(
        prepare(RunSpec("sac-twin-q", MOUNTAINCAR, 0, 300, 100, 1, dict(TINY))),
        tmp_path,
        device="cuda",
    )
    ppo = execute(prepare(RunSpec("ppo", MOUNTAINCAR, 0, 300, 100, 1, {})), tmp_path, device="cuda")
    assert sac.provenance["device"].startswith("cuda (")
    assert ppo.provenance["device"] == "cpu"  # no GPU path: it says where it really ran
    assert np.isfinite(sac.final_return)
    assert json.loads((sac.path / "provenance.json").read_text())["device"].startswith("cuda")


def test_grid_workers_use_one_device_unless_the_gpu_ones_are_limited(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert worker_devices("auto", 3) == ["cuda"] * 3  # a run's device: its algorithm's
    assert worker_devices("auto", 6, 2) == ["cuda", "cuda", "cpu", "cpu", "cpu", "cpu"]
    assert worker_devices("auto", 1, 2) == ["cuda"]
    assert worker_devices("cuda", 3, 1) == ["cuda"] * 3  # asked for: every worker
    assert worker_devices("cpu", 2, 2) == ["cpu"] * 2
    with pytest.raises(ValueError, match=">= 0"):
        worker_devices("auto", 2, -1)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert worker_devices("auto", 3, 2) == ["cpu"] * 3


def _interrupted_run(store, checkpoint_device: str):
    """A run (a seed batch of one) whose checkpoint was made on ``checkpoint_device``; the
    checkpoint's path and the run's hidden directory."""
    prepared = prepare(RunSpec("sac", MOUNTAINCAR, 0, 400, 100, 1, dict(TINY)))
    batch_dir = store / f".{batch_id([prepared])}"
    save_checkpoint(batch_dir / CHECKPOINT_FILE, {"step": 200, "device": checkpoint_device})
    (batch_dir / "segments.json").write_text(
        json.dumps([{"wall_time_s": 1.0, "device": checkpoint_device}])
    )
    work = partial_directory(prepared, store)
    work.mkdir(parents=True)
    (work / "curve.csv").write_text(",".join(CURVE_COLUMNS) + "\n0,1.0,0,1.0,nan,,nan,0.5\n")
    return prepared, batch_dir / CHECKPOINT_FILE, work


def test_a_resume_follows_its_checkpoint_under_auto_and_is_refused_otherwise(tmp_path, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    prepared, checkpoint, work = _interrupted_run(
        tmp_path, "cuda (NVIDIA H100 80GB HBM3, CUDA 13.0)"
    )
    # no GPU here: the CUDA checkpoint cannot be followed, whatever was asked
    for device in ("auto", "cpu"):
        with pytest.raises(HarnessError, match="made on cuda"):
            execute(prepared, tmp_path, device=device)
        assert checkpoint.is_file()  # the run's progress is not thrown away
        assert "0,1.0,0,1.0" in (work / "curve.csv").read_text()  # nor its curve


def test_a_cpu_checkpoint_is_resumed_on_cpu_by_a_gpu_worker_under_auto(tmp_path, monkeypatch):
    import baselines.registry

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    prepared, _, _ = _interrupted_run(tmp_path, "cpu")
    seen = {}

    class Stop(Exception):
        pass

    def record_device(bctx, configs):
        seen["device"] = bctx.device
        raise Stop  # nothing is trained: only the choice of device is under test

    algorithm = baselines.registry.get_algorithm("sac")
    monkeypatch.setitem(
        baselines.registry._REGISTRY,
        "sac",
        dataclasses.replace(algorithm, train_batch=record_device),
    )
    with pytest.raises(Stop):
        execute(prepared, tmp_path, device="cuda", follow_checkpoint=True)
    assert seen["device"] == "cpu"


def test_an_expert_checkpoint_from_a_gpu_is_refused_here_and_kept(tmp_path, monkeypatch):
    from replicate import experts

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    (run,) = experts.expert_runs("Hopper-v5", 200, [0], 10_000, 5, "sac", 1)
    store = experts.work_dir_for("Hopper-v5", tmp_path)
    checkpoint = store / f".{batch_id([run])}" / CHECKPOINT_FILE
    save_checkpoint(checkpoint, {"step": 100, "device": "cuda"})
    (checkpoint.parent / "segments.json").write_text(
        json.dumps([{"wall_time_s": 1.0, "device": "cuda (NVIDIA H100 80GB HBM3, CUDA 13.0)"}])
    )
    with pytest.raises(HarnessError, match="made on cuda"):
        experts.train_expert("Hopper-v5", steps=200, root=tmp_path, algo="sac")
    assert checkpoint.is_file()
