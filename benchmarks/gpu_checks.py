"""Checks of the batched trainer on a GPU, to run before its bench on a GPU machine:
a batched gradient step on CUDA against the same step on CPU, and a short batch trained
through the runner (graph capture, checkpoint, provenance).

    python benchmarks/gpu_checks.py OUT_DIR
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from baselines.common.buffer import Batch  # noqa: E402
from baselines.sac import SACAgent, SACConfig  # noqa: E402
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig  # noqa: E402


def step_agreement(twin_q: bool) -> float:
    """Largest |difference| of the losses and weights after 3 steps of a batch of 4, CUDA
    against CPU (the same seeds, so the same initial weights)."""
    cfg_cls, agent_cls = (TwinQSACConfig, TwinQSACAgent) if twin_q else (SACConfig, SACAgent)
    cfg, seeds = cfg_cls(), list(range(4))
    cpu = agent_cls(seeds, "Hopper-v5", cfg, "cpu")
    gpu = agent_cls(seeds, "Hopper-v5", cfg, "cuda", cuda_graphs=False)
    g = torch.Generator().manual_seed(0)
    worst = 0.0
    for _ in range(3):
        batch = Batch(
            torch.randn(4, 256, 11, generator=g),
            torch.rand(4, 256, 3, generator=g),
            torch.randn(4, 256, generator=g),
            torch.randn(4, 256, 11, generator=g),
            (torch.rand(4, 256, generator=g) < 0.1).float(),
        )
        noise = torch.randn(4, 256, 3, generator=g)
        noise = (noise, torch.randn(4, 256, 3, generator=g)) if twin_q else noise
        on_gpu = Batch(*[t.cuda() for t in vars(batch).values()])
        gpu_noise = tuple(n.cuda() for n in noise) if twin_q else noise.cuda()
        a, b = cpu._gradient_step(batch, noise), gpu._gradient_step(on_gpu, gpu_noise)
        worst = max(worst, max(float((a[k] - b[k].cpu()).abs().max()) for k in a))
    for p, q in zip(cpu.policy.parameters(), gpu.policy.parameters()):
        worst = max(worst, float((p.detach() - q.detach().cpu()).abs().max()))
    return worst


def batch_through_runner(out: Path) -> dict:
    from replicate.store.runner import execute_batch, prepare
    from replicate.store.spec import RunSpec

    store = Path(tempfile.mkdtemp())
    hyper = {"learning_starts": 200}
    members = [
        prepare(RunSpec("drl-eg", "Hopper-v5", s, 1500, 500, 2, {**hyper, "guide_threshold": 0.5}))
        for s in range(3)
    ]
    outcome = execute_batch(members, store, device="cuda", checkpoint_interval=400, env_workers=2)
    return {
        "runs": [r.path.name for r in outcome.runs],
        "failed": outcome.failed,
        "final_returns": [r.final_return for r in outcome.runs],
        "provenance_batch": outcome.runs[0].provenance.get("batch"),
        "guided_fraction": [float(r.curve["guided_fraction"].iloc[-1]) for r in outcome.runs],
    }


if __name__ == "__main__":
    if not torch.cuda.is_available():
        sys.exit("gpu_checks.py needs a CUDA GPU, and torch sees none")
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    results = {
        "gpu": torch.cuda.get_device_name(),
        "torch": torch.__version__,
        "sac step |cuda - cpu| max": step_agreement(False),
        "twin-q step |cuda - cpu| max": step_agreement(True),
    }
    print(json.dumps(results), flush=True)
    results["runner"] = batch_through_runner(out)
    print(json.dumps(results), flush=True)
    (out / "gpu_checks.json").write_text(json.dumps(results, indent=1, default=str) + "\n")
