"""Does a bf16-autocast update keep SAC's learning curve? Hopper-v5, the paper's V-SAC, 3 seeds
trained as one seed batch on one core, fp32 against bf16 autocast of the CPU update (the
same seeds, so the same initial weights), 50k env steps, 5 evaluation episodes every 5k.

    python benchmarks/bf16_curves.py fp32 OUT.json      # one process per precision
    python benchmarks/bf16_curves.py bf16 OUT.json

Writes each evaluation curve and the wall time; ``--compare A.json B.json`` prints whether
the bf16 seeds' mean curve stays inside the fp32 seeds' 95% bootstrap band at every point.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from baselines.common.context import BatchContext, TrainContext  # noqa: E402
from baselines.common.device import flush_denormals  # noqa: E402
from baselines.offpolicy import PolicyExplorer, run_off_policy  # noqa: E402
from baselines.registry import get_algorithm  # noqa: E402
from baselines.sac import SACAgent  # noqa: E402

SEEDS, STEPS, INTERVAL, EPISODES = (0, 1, 2), 50_000, 5_000, 5


def train(precision: str) -> dict:
    torch.set_num_threads(1)
    curves: dict[int, list] = {seed: [] for seed in SEEDS}
    contexts = [
        TrainContext(
            "Hopper-v5",
            seed,
            STEPS,
            INTERVAL,
            EPISODES,
            on_eval=lambda p, s=seed: curves[s].append(p),
        )
        for seed in SEEDS
    ]
    bctx = BatchContext(contexts)
    config = get_algorithm("sac").make_config({})
    agent = SACAgent(bctx.seeds, "Hopper-v5", config)
    agent.cpu_autocast = torch.bfloat16 if precision == "bf16" else None
    started = time.time()
    with flush_denormals():  # as every registered trainer runs (baselines/registry.py)
        run_off_policy(bctx, agent, PolicyExplorer(agent))
    return {
        "precision": precision,
        "wall_s": round(time.time() - started, 1),
        "curves": {
            seed: [[p.step, p.mean_return] for p in points] for seed, points in curves.items()
        },
    }


def band(
    curves: np.ndarray, rng: np.random.Generator, draws: int = 10_000
) -> tuple[np.ndarray, np.ndarray]:
    """95% bootstrap band of the mean over seeds (rows), at every step (columns)."""
    picks = rng.integers(0, len(curves), size=(draws, len(curves)))
    means = curves[picks].mean(axis=1)
    return np.percentile(means, 2.5, axis=0), np.percentile(means, 97.5, axis=0)


def compare(fp32_path: str, bf16_path: str) -> dict:
    fp32, bf16 = (json.loads(Path(p).read_text()) for p in (fp32_path, bf16_path))

    def as_array(r):
        return np.array([[v for _, v in c] for c in r["curves"].values()])

    a, b = as_array(fp32), as_array(bf16)
    low, high = band(a, np.random.default_rng(0))
    mean_b = b.mean(axis=0)
    inside = (mean_b >= low) & (mean_b <= high)
    steps = [s for s, _ in next(iter(fp32["curves"].values()))]
    return {
        "steps": steps,
        "fp32 mean": a.mean(0).round(1).tolist(),
        "fp32 band": [low.round(1).tolist(), high.round(1).tolist()],
        "bf16 mean": mean_b.round(1).tolist(),
        "inside at every point": bool(inside.all()),
        "points inside": f"{int(inside.sum())}/{len(inside)}",
        "wall s fp32, bf16": [fp32["wall_s"], bf16["wall_s"]],
    }


if __name__ == "__main__":
    if sys.argv[1] == "--compare":
        print(json.dumps(compare(sys.argv[2], sys.argv[3]), indent=1))
    else:
        result = train(sys.argv[1])
        Path(sys.argv[2]).write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps({"precision": result["precision"], "wall_s": result["wall_s"]}))
