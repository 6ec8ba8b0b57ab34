"""benchmarks/gpu_checks.py: its checks pass on CPU at tiny sizes, and fail where the GPU
path's former faults would make them fail."""

import json

import numpy as np
import pytest
import torch

from baselines import training_loop
from baselines.common.stacked import StackedReplay
from benchmarks import gpu_checks
from benchmarks.gpu_checks import CHECKS, SMALL, CheckFailed

SLOW = {"cuda-untouched", "kill-resume", "gpu-tests", "graphed-vs-eager"}  # 5-15 s each


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=[pytest.mark.slow] if n in SLOW else []) for n in CHECKS]
)
def test_each_check_passes_on_cpu(name, tmp_path):
    assert CHECKS[name]("cpu", SMALL, tmp_path)


def test_the_script_writes_its_section_beside_the_others_and_fails_with_a_check(
    tmp_path, monkeypatch
):
    out = tmp_path / "bench_gpu.json"
    out.write_text(json.dumps({"measurements": {"kept": 1.0}}))
    args = ["--device", "cpu", "--small", "--only", "checkpoint-memory", str(out)]
    assert gpu_checks.main(args) == 0
    written = json.loads(out.read_text())
    assert written["measurements"] == {"kept": 1.0}
    assert written["gpu_checks"]["checks"]["checkpoint-memory"]["ok"]
    assert written["gpu_checks"]["failed"] == []

    def broken(device, sizes, work):
        gpu_checks.require(False, "what was expected, what was found")

    monkeypatch.setitem(CHECKS, "checkpoint-memory", broken)
    assert gpu_checks.main(args) == 1
    entry = json.loads(out.read_text())["gpu_checks"]["checks"]["checkpoint-memory"]
    assert not entry["ok"] and entry["error"] == "what was expected, what was found"


@pytest.mark.skipif(torch.cuda.is_available(), reason="a machine without a GPU")
def test_on_a_cpu_only_torch_the_gpu_run_is_refused(tmp_path, capsys):
    out = tmp_path / "bench_gpu.json"
    assert gpu_checks.main([str(out)]) == 2
    err = capsys.readouterr().err
    assert "CPU-only build" in err or "sees no GPU" in err
    assert not out.exists()


def test_a_cpu_run_that_initialises_cuda_fails_its_check(tmp_path):
    """A fork of every device's random stream, as fork_rng() without devices does."""
    touch = "import torch\nwith torch.random.fork_rng():\n    pass"
    with pytest.raises(CheckFailed, match="touched CUDA"):
        gpu_checks.cuda_untouched("cpu", SMALL, tmp_path, prelude=touch, algos=("sac",))


def test_a_nan_member_that_reaches_the_batch_fails_the_poison_check(tmp_path, monkeypatch):
    """As before the member's actions were checked: its NaN action reaches its env, its NaN
    state the KD-tree all members share, and the runner discards the whole batch."""

    class Blind:  # numpy, but every number looks finite to the trainer
        def __getattr__(self, name):
            return getattr(np, name)

        @staticmethod
        def isfinite(x):
            return np.ones(np.shape(x), dtype=bool)

    monkeypatch.setattr(training_loop, "np", Blind())
    with pytest.raises(CheckFailed, match="failed as a whole"):
        CHECKS["poison-drl-eg"]("cpu", SMALL, tmp_path)


@pytest.mark.slow
def test_a_resume_that_loses_the_noise_streams_fails_the_kill_resume_check(tmp_path, monkeypatch):
    original = training_loop.load_agent_state

    def forgetful(agent, state):
        original(agent, {**state, "noise": agent.noise_state()})

    monkeypatch.setattr(training_loop, "load_agent_state", forgetful)
    with pytest.raises(CheckFailed, match="resumed curve differs"):
        CHECKS["kill-resume"]("cpu", SMALL, tmp_path)


def test_a_checkpoint_of_the_whole_replay_fails_the_memory_check(tmp_path, monkeypatch):
    monkeypatch.setattr(
        StackedReplay, "state_dict", lambda self: {"data": self.data.clone(), "position": 0}
    )
    with pytest.raises(CheckFailed):
        CHECKS["checkpoint-memory"]("cpu", SMALL, tmp_path)
