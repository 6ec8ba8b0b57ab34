"""Experts: the harness trains its own, with its own SAC, and rolls them out for demonstrations.

The paper took its MuJoCo demonstrations from "the best trained SAC or TD3 agent" and never
released them. Here an expert is a SAC run that checkpoints into a work directory
(``experts/<env>/`` by default, not committed: it holds the replay buffer) and resumes from
there when started again, so an expert can be trained in several parts. The policy
with the best evaluation so far is kept; exporting writes it with its provenance into the
package (``replicate/data/experts``), small enough to commit.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from baselines.common.checkpoint import CheckpointDeviceError, save_checkpoint
from baselines.common.context import EvalPoint, TrainContext
from baselines.common.device import describe_device, device_kind, resolve_device, resume_device
from baselines.common.networks import TanhGaussianPolicy
from baselines.registry import get_algorithm
from envs import env_spec, make_env
from replicate import provenance
from replicate.devices import check_device
from replicate.errors import HarnessError

EXPERT_DATA_DIR = "data/experts"
EXPERT_ALGOS = ("sac", "sac-twin-q")
# The paper's V-network SAC by default; on Ant it stayed standing for 130k steps (the
# healthy reward's local optimum), so Ant's expert is the twin-Q, learned-temperature SAC,
# as are Hopper's (its V-SAC expert's demonstrations stopped at 2917, under the 3000 target)
# and Walker2d's and HalfCheetah's (V-SAC: 1465 at 100k and 1590 at 200k steps).
DEFAULT_EXPERT_ALGO: dict[str, str] = {
    "Ant-v5": "sac-twin-q",
    "Hopper-v5": "sac-twin-q",
    "Walker2d-v5": "sac-twin-q",
    "HalfCheetah-v5": "sac-twin-q",
}


def expert_algo_for(env_id: str) -> str:
    """The algorithm that trains ``env_id``'s expert unless one is named."""
    return DEFAULT_EXPERT_ALGO.get(env_id, "sac")


# A sparse-reward task takes the expert of its dense twin: same dynamics and observations.
EXPERT_SOURCE: dict[str, str] = {
    "dm_control/cartpole-swingup_sparse-v0": "dm_control/cartpole-swingup-v0",
}
EXPERT_ENVS = (
    "Hopper-v5",
    "Walker2d-v5",
    "HalfCheetah-v5",
    "Ant-v5",
    "dm_control/cartpole-swingup-v0",
    "dm_control/ball_in_cup-catch-v0",
    "dm_control/walker-walk-v0",
)


def _file_name(env_id: str) -> str:
    return env_id.replace("/", "__")


def expert_path(env_id: str) -> Path:
    """Where the committed expert policy of ``env_id`` lives inside the package."""
    from importlib import resources

    source = EXPERT_SOURCE.get(env_id, env_id)
    return Path(
        str(resources.files("replicate").joinpath(EXPERT_DATA_DIR, f"{_file_name(source)}.pt"))
    )


def expert_training_curve(env_id: str) -> dict[str, Any] | None:
    """The evaluation curve of the run that trained ``env_id``'s committed expert (its
    file's metadata): the algorithm, the seed, the steps and the mean evaluation returns,
    and ``best_of``, how many of a seed batch's members it was chosen from (so its curve is
    the luckiest seed's), else None. None where no expert is committed, or its file records
    no curve."""
    path = expert_path(env_id)
    if not path.is_file():
        return None
    metadata = torch.load(path, weights_only=True, map_location="cpu")["metadata"]
    curve = metadata.get("curve")
    if not curve:
        return None
    curve = json.loads(curve) if isinstance(curve, str) else curve
    return {
        "algo": metadata["algo"],
        "seed": metadata["seed"],
        "steps": [int(step) for step, _ in curve],
        "returns": [float(value) for _, value in curve],
        "best_of": len(metadata.get("batch_best_eval_return", {})) or None,
    }


def work_dir_for(env_id: str, root: Path) -> Path:
    return Path(root) / _file_name(env_id)


def _checked_request(env_id: str, steps: int, algo: str | None) -> str:
    """The trainer of ``env_id``'s expert, after refusing a request that cannot train one."""
    env_spec(env_id)
    algo = algo or expert_algo_for(env_id)
    if algo not in EXPERT_ALGOS:
        raise HarnessError(
            f"experts are trained by {' or '.join(EXPERT_ALGOS)}, not {algo}",
            f"pass --algo {EXPERT_ALGOS[0]} or --algo {EXPERT_ALGOS[1]}",
        )
    if env_id in EXPERT_SOURCE:
        raise HarnessError(
            f"{env_id} takes its expert from {EXPERT_SOURCE[env_id]}",
            f"train that one: --env {EXPERT_SOURCE[env_id]}",
        )
    if steps <= 0:
        raise HarnessError(f"step count must be positive, got {steps}", "pass --steps N, N > 0")
    return algo


def train_expert(
    env_id: str,
    steps: int,
    root: Path = Path("experts"),
    seed: int = 0,
    eval_interval: int = 10_000,
    eval_episodes: int = 5,
    checkpoint_interval: int = 10_000,
    on_steps: Callable[[int], None] = lambda n: None,
    algo: str | None = None,
    threads: int = 1,
    device: str = "auto",
) -> Path:
    """Train (or resume) the SAC expert of ``env_id`` up to ``steps``; export it; return its
    path."""
    algo = _checked_request(env_id, steps, algo)
    work = work_dir_for(env_id, root)
    work.mkdir(parents=True, exist_ok=True)
    progress_file = work / "progress.json"
    previous = json.loads(progress_file.read_text()) if progress_file.is_file() else {}
    if previous.get("total_steps", steps) != steps:
        # the budget is part of the run (beta-free SAC has no schedule, but keep it honest)
        raise HarnessError(
            f"{work} holds an expert run with budget {previous['total_steps']}, not {steps}",
            f"pass --steps {previous['total_steps']} or remove {work}",
        )
    if previous.get("algo", algo) != algo:
        raise HarnessError(
            f"{work} holds an expert run of {previous['algo']}, not {algo}",
            f"pass --algo {previous['algo']} or remove {work}",
        )
    earlier_wall = float(previous.get("wall_time_s_before_this_sitting", 0.0))
    earlier_wall += float(previous.get("wall_time_s_this_sitting", 0.0))
    started = time.time()
    curve: list[EvalPoint] = []

    def on_eval(point: EvalPoint) -> None:
        curve.append(point)
        best = max(curve, key=lambda p: p.mean_return)
        progress_file.write_text(
            json.dumps(
                {
                    "env_id": env_id,
                    "algo": algo,
                    "seed": seed,
                    "total_steps": steps,
                    "torch_threads": threads,
                    "device": describe_device(resolved_device),
                    "steps_done": point.step,
                    "best_step": best.step,
                    "best_mean_return": best.mean_return,
                    "curve": [[p.step, round(p.mean_return, 3)] for p in curve],
                    "wall_time_s_before_this_sitting": earlier_wall,
                    "wall_time_s_this_sitting": time.time() - started,
                },
                indent=1,
            )
        )

    if threads < 1:
        raise HarnessError(f"thread count must be positive, got {threads}", "pass --threads 1")
    algorithm = get_algorithm(algo)
    check_device(device)
    resolved_device = resolve_device(device, algorithm.gpu)
    saved_on = device_kind(previous.get("device", "cpu"))
    try:
        resolved_device = resume_device(
            resolved_device,
            saved_on if (work / "checkpoint.pt").is_file() else None,
            follow=device == "auto",
            what=f"the {env_id} expert ({work})",
        )
    except CheckpointDeviceError as exc:
        raise HarnessError(
            str(exc), f"pass --device {saved_on} (or auto), or remove {work}"
        ) from None
    # one expert alone on a machine may use every core for its matrix products
    config = algorithm.make_config({"torch_threads": threads})
    ctx = TrainContext(
        env_id=env_id,
        seed=seed,
        total_steps=steps,
        eval_interval=eval_interval,
        eval_episodes=eval_episodes,
        on_eval=on_eval,
        on_steps=on_steps,
        checkpoint_path=work / "checkpoint.pt",
        checkpoint_interval=checkpoint_interval,
        best_policy_path=work / "best_policy.pt",
        device=resolved_device,
    )
    try:
        algorithm.train(ctx, config)
    except CheckpointDeviceError as exc:
        raise HarnessError(
            str(exc), f"pass --device {saved_on} (or auto), or remove {work}"
        ) from None
    except torch.OutOfMemoryError:
        raise HarnessError(
            f"the {env_id} expert ran out of GPU memory; its last checkpoint is kept",
            "run the same command again, or with --device cpu",
        ) from None
    (work / "checkpoint.pt").unlink(missing_ok=True)  # finished: the buffer is not needed
    return export_expert(env_id, root)


class _TimeUp(Exception):
    """Raised from the progress callback when a time-limited expert batch is out of time."""


def train_expert_batch(
    env_id: str,
    steps: int,
    seeds: list[int],
    root: Path = Path("experts"),
    eval_interval: int = 10_000,
    eval_episodes: int = 5,
    on_steps: Callable[[int], None] = lambda n: None,
    algo: str | None = None,
    device: str = "auto",
    env_workers: int | None = None,
    time_limit_s: float | None = None,
) -> Path:
    """Train one expert run per seed as one seed batch, keep the member with the best
    evaluation, export it and return the path.

    For a GPU machine: several seeds cost little more time than one, and
    the best of them is kept (as the paper kept "the best trained" agent). With
    ``time_limit_s`` the batch stops at the first step after that many seconds; every
    member's best policy so far is on disk at each evaluation, so stopping loses nothing
    kept. A batch is not resumed: it writes ``<root>/<env>/batch/seed-<s>/`` afresh.
    """
    from baselines.batched import BatchContext
    from baselines.registry import batched_trainer

    algo = _checked_request(env_id, steps, algo)
    if len(set(seeds)) != len(seeds) or len(seeds) < 2:
        raise HarnessError(
            f"an expert batch needs two or more distinct seeds, got {seeds}",
            "pass --seeds 1-8 (or --seed N for one run)",
        )
    work = work_dir_for(env_id, root)
    if (work / "checkpoint.pt").is_file():
        raise HarnessError(
            f"{work} holds a one-run expert in training",
            "finish or remove it, or pass another --root",
        )
    check_device(device)
    resolved_device = resolve_device(device, True)
    workers = (
        env_workers if env_workers is not None else (0 if resolved_device == "cpu" else len(seeds))
    )
    started = time.time()
    members_dir = work / "batch"
    curves: dict[int, list[EvalPoint]] = {seed: [] for seed in seeds}

    def progress(seed: int, point: EvalPoint) -> None:
        curve = curves[seed]
        curve.append(point)
        best = max(curve, key=lambda p: p.mean_return)
        (members_dir / f"seed-{seed}" / "progress.json").write_text(
            json.dumps(
                {
                    "env_id": env_id,
                    "algo": algo,
                    "seed": seed,
                    "total_steps": steps,
                    "torch_threads": 1,
                    "device": describe_device(resolved_device),
                    "steps_done": point.step,
                    "best_step": best.step,
                    "best_mean_return": best.mean_return,
                    "curve": [[p.step, round(p.mean_return, 3)] for p in curve],
                    "batch_seeds": list(seeds),
                    "time_limit_s": time_limit_s,
                    "wall_time_s_before_this_sitting": 0.0,
                    "wall_time_s_this_sitting": time.time() - started,
                },
                indent=1,
            )
        )

    def count(n: int) -> None:
        on_steps(n)
        if time_limit_s is not None and time.time() - started > time_limit_s:
            raise _TimeUp

    contexts = []
    for seed in seeds:
        (members_dir / f"seed-{seed}").mkdir(parents=True, exist_ok=True)
        (members_dir / f"seed-{seed}" / "best_policy.pt").unlink(missing_ok=True)
        contexts.append(
            TrainContext(
                env_id=env_id,
                seed=seed,
                total_steps=steps,
                eval_interval=eval_interval,
                eval_episodes=eval_episodes,
                on_eval=lambda p, s=seed: progress(s, p),
                best_policy_path=members_dir / f"seed-{seed}" / "best_policy.pt",
                device=resolved_device,
            )
        )
    algorithm = get_algorithm(algo)
    config = algorithm.make_config({"torch_threads": 1})
    bctx = BatchContext(contexts, device=resolved_device, env_workers=workers, on_steps=count)
    try:
        batched_trainer(algo)(bctx, [config] * len(seeds))
    except _TimeUp:
        pass
    except torch.OutOfMemoryError:
        raise HarnessError(
            f"the {env_id} expert batch ran out of GPU memory",
            "pass fewer --seeds, or --device cpu",
        ) from None
    trained = [s for s in seeds if (members_dir / f"seed-{s}" / "best_policy.pt").is_file()]
    if not trained:
        raise HarnessError(
            f"no member of the {env_id} expert batch finished an evaluation",
            "give it more time (--minutes)",
        )
    chosen = max(trained, key=lambda s: max(p.mean_return for p in curves[s]))
    chosen_dir = members_dir / f"seed-{chosen}"
    summary = json.loads((chosen_dir / "progress.json").read_text())
    summary["batch_best"] = {str(s): max(p.mean_return for p in curves[s]) for s in trained}
    (work / "progress.json").write_text(json.dumps(summary, indent=1))
    (work / "best_policy.pt").write_bytes((chosen_dir / "best_policy.pt").read_bytes())
    return export_expert(env_id, root)


def export_expert(env_id: str, root: Path = Path("experts")) -> Path:
    """Write the best policy so far, with its provenance, to the package's expert file."""
    work = work_dir_for(env_id, root)
    best_file, progress_file = work / "best_policy.pt", work / "progress.json"
    if not best_file.is_file() or not progress_file.is_file():
        raise HarnessError(
            f"no expert training found in {work}",
            f"train one first: python -m replicate expert --env {env_id}",
        )
    best = torch.load(best_file, weights_only=True, map_location="cpu")
    progress = json.loads(progress_file.read_text())
    algo = progress.get("algo", "sac")
    config = get_algorithm(algo).make_config({"torch_threads": progress.get("torch_threads", 1)})
    metadata = {
        "env_id": env_id,
        "algo": algo,
        "seed": progress["seed"],
        "hidden_sizes": list(config.hidden_sizes),
        "hyperparameters": {
            k: (list(v) if isinstance(v, tuple) else v)
            for k, v in dataclasses.asdict(config).items()
        },
        "budget_steps": progress["total_steps"],
        "steps_trained": progress["steps_done"],
        # a batch keeps its best member; every member's best evaluation, by seed
        **({"batch_best_eval_return": progress["batch_best"]} if "batch_best" in progress else {}),
        "best_step": int(best["step"]),
        "best_eval_return": float(best["mean_return"]),
        "wall_time_s": round(
            progress["wall_time_s_before_this_sitting"] + progress["wall_time_s_this_sitting"], 1
        ),
        "curve": progress["curve"],
        "command": f"python -m replicate expert --env {env_id} --steps {progress['total_steps']}"
        + (
            f" --seeds {','.join(map(str, progress['batch_seeds']))}"
            if "batch_seeds" in progress
            else ""
        )
        + (f" --minutes {progress['time_limit_s'] / 60:g}" if progress.get("time_limit_s") else "")
        + ("" if algo == expert_algo_for(env_id) else f" --algo {algo}")
        + (
            ""
            if progress.get("torch_threads", 1) == 1
            else f" --threads {progress['torch_threads']}"
        ),
        "git_revision": provenance.git_revision(),
        "device": progress.get("device", "cpu"),
    }
    # CPU training reproduces bit for bit; the command names the device it ran on
    metadata["command"] += " --device " + (
        "cuda" if metadata["device"].startswith("cuda") else "cpu"
    )
    # half precision halves the committed file; demonstrations are rolled out from these
    # rounded weights, so the files and the returns they record agree
    metadata["weights_dtype"] = "float16"
    half = {name: (t.half() if t.is_floating_point() else t) for name, t in best["policy"].items()}
    out = expert_path(env_id)
    save_checkpoint(out, {"policy": half, "metadata": metadata})
    return out


class ExpertPolicy:
    """A committed expert: the deterministic action of its SAC policy."""

    def __init__(self, env_id: str, path: Path | None = None):
        path = Path(path) if path else expert_path(env_id)
        if not path.is_file():
            raise HarnessError(
                f"no expert for {env_id} at {path}",
                f"train one: python -m replicate expert --env "
                f"{EXPERT_SOURCE.get(env_id, env_id)} --steps 1000000",
            )
        saved = torch.load(path, weights_only=True, map_location="cpu")
        self.metadata: dict[str, Any] = saved["metadata"]
        env = make_env(env_id)
        space = env.action_space
        self.policy = TanhGaussianPolicy(
            env.observation_space.shape[0],
            space.shape[0],
            space.low,
            space.high,
            tuple(self.metadata["hidden_sizes"]),
        )
        env.close()
        self.policy.load_state_dict(
            {
                name: (t.float() if t.is_floating_point() else t)
                for name, t in saved["policy"].items()
            }
        )
        self.policy.eval()

    @torch.no_grad()
    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs_t = torch.as_tensor(obs, dtype=torch.float32).unsqueeze(0)
        return self.policy.deterministic(obs_t).squeeze(0).numpy()
