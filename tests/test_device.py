"""Device choice, the CUDA-graph update, and checkpoints that cross devices.

The tests marked ``cuda`` run only where torch sees a GPU (never in CI); the rest check on
CPU what a user without a GPU meets.
"""

import json

import numpy as np
import pytest
import torch

from baselines.common.buffer import ReplayBuffer
from baselines.common.checkpoint import save_checkpoint
from baselines.common.device import DeviceUnavailableError, resolve_device, worker_devices
from baselines.sac import SACAgent, SACConfig
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig
from replicate.cli import main
from replicate.errors import HarnessError
from replicate.runner import CHECKPOINT_FILE, execute, partial_directory, prepare
from replicate.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


@pytest.mark.parametrize("gpu_present, requested, has_gpu_path, expected", [
    (False, "auto", True, "cpu"),
    (True, "auto", True, "cuda"),
    (True, "auto", False, "cpu"),  # PPO and DDPGfD stay on CPU
    (True, "cuda", False, "cpu"),
    (True, "cpu", True, "cpu"),
    (True, "cuda", True, "cuda"),
])
def test_device_resolution(monkeypatch, gpu_present, requested, has_gpu_path, expected):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: gpu_present)
    assert resolve_device(requested, has_gpu_path) == expected


def test_asking_for_cuda_without_a_gpu_fails_and_names_the_way_out(monkeypatch, tmp_path,
                                                                    capsys):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(DeviceUnavailableError):
        resolve_device("cuda", True)
    with pytest.raises(ValueError, match="unknown device"):
        resolve_device("tpu", True)
    store = tmp_path / "store"
    code = main(["train", "--algo", "sac", "--env", MOUNTAINCAR, "--steps", "10",
                 "--device", "cuda", "--store", str(store)])
    err = capsys.readouterr().err
    assert code == 2 and "no CUDA GPU" in err and "--device cpu" in err
    assert not store.exists() or not any(store.iterdir())


def test_provenance_names_the_device(tmp_path):
    spec = RunSpec("sac", MOUNTAINCAR, 0, 120, 60, 1, dict(TINY))
    run = execute(prepare(spec), tmp_path, device="cpu")
    assert run.provenance["device"] == "cpu"


def test_a_checkpoint_from_another_device_is_refused_and_kept(tmp_path):
    prepared = prepare(RunSpec("sac", MOUNTAINCAR, 0, 400, 100, 1, dict(TINY)))
    checkpoint = partial_directory(prepared, tmp_path) / CHECKPOINT_FILE
    save_checkpoint(checkpoint, {"step": 200, "device": "cuda"})
    with pytest.raises(HarnessError, match="made on cuda"):
        execute(prepared, tmp_path, device="cpu")
    assert checkpoint.is_file()  # the run's progress is not thrown away


def _agents(kind: str, device: str):
    """Two agents of one seed: one replays its update as a CUDA graph, one runs it eagerly."""
    if kind == "sac":
        make = lambda graphs: SACAgent(11, 3, -np.ones(3), np.ones(3), SACConfig(), seed=0,
                                       device=device, cuda_graphs=graphs)
    else:
        make = lambda graphs: TwinQSACAgent(11, 3, -np.ones(3), np.ones(3), TwinQSACConfig(),
                                            seed=0, device=device, cuda_graphs=graphs)
    return make(True), make(False)


def _filled_buffer() -> ReplayBuffer:
    rng = np.random.default_rng(0)
    buffer = ReplayBuffer(11, 3, 2000)
    for _ in range(2000):
        buffer.add(rng.normal(size=11), rng.uniform(-1, 1, 3), rng.normal(),
                   rng.normal(size=11), rng.random() < 0.05)
    return buffer


@cuda
@pytest.mark.parametrize("kind", ["sac", "sac-twin-q"])
def test_graphed_updates_follow_the_eager_ones(kind):
    graphed, eager = _agents(kind, "cuda")
    buffer = _filled_buffer()
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
    for _ in range(12):  # warm-up, capture, then replays
        got = {k: float(v) for k, v in graphed.update(buffer.sample(256, rng_a)).items()}
        want = {k: float(v) for k, v in eager.update(buffer.sample(256, rng_b)).items()}
        for name in want:
            assert got[name] == pytest.approx(want[name], rel=1e-4, abs=1e-5), name
    for a, b in zip(graphed.policy.parameters(), eager.policy.parameters(), strict=True):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-5)
    assert graphed.gradient_step.graph is not None and eager.gradient_step.graph is None


@cuda
def test_runs_train_on_the_gpu_and_say_so(tmp_path):
    sac = execute(prepare(RunSpec("sac-twin-q", MOUNTAINCAR, 0, 300, 100, 1, dict(TINY))),
                  tmp_path, device="cuda")
    ppo = execute(prepare(RunSpec("ppo", MOUNTAINCAR, 0, 300, 100, 1, {})), tmp_path,
                  device="cuda")
    assert sac.provenance["device"].startswith("cuda (")
    assert ppo.provenance["device"] == "cpu"  # no GPU path: it says where it really ran
    assert np.isfinite(sac.final_return)
    assert json.loads((sac.path / "provenance.json").read_text())["device"].startswith("cuda")


def test_a_grid_with_a_gpu_keeps_a_few_workers_on_it_and_the_rest_on_the_cpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert worker_devices("auto", 6, 2) == ["cuda", "cuda", "cpu", "cpu", "cpu", "cpu"]
    assert worker_devices("auto", 1, 2) == ["cuda"]
    assert worker_devices("cuda", 3, 1) == ["cuda"] * 3  # asked for: every worker
    assert worker_devices("cpu", 2, 2) == ["cpu"] * 2
    with pytest.raises(ValueError, match=">= 0"):
        worker_devices("auto", 2, -1)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert worker_devices("auto", 3, 2) == ["cpu"] * 3


def test_running_out_of_gpu_memory_keeps_the_run_to_resume(tmp_path, monkeypatch):
    import baselines.sac

    def out_of_memory(*args, **kwargs):
        raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 MiB")

    monkeypatch.setattr(baselines.sac, "run_off_policy", out_of_memory)
    prepared = prepare(RunSpec("sac", MOUNTAINCAR, 0, 120, 60, 1, dict(TINY)))
    with pytest.raises(HarnessError, match="ran out of GPU memory"):
        execute(prepared, tmp_path, device="cpu")
    assert partial_directory(prepared, tmp_path).is_dir()  # not removed as a code error
