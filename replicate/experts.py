"""Experts: the harness trains its own, with its own SAC, and rolls them out for demonstrations.

The paper took its MuJoCo demonstrations from "the best trained SAC or TD3 agent" and never
released them. Here an expert is an ordinary run of SAC or twin-Q SAC with the
``keep_best_policy`` setting, in a run store of its own (``experts/<env>/`` by default, not
committed): it checkpoints, resumes and trains in seed batches as every run does, and keeps
the policy with the best evaluation so far beside its curve. Exporting writes the best such
policy, with its provenance, into the package (``replicate/data/experts``), small enough to
commit.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from baselines.common.checkpoint import TimeLimitReached, save_checkpoint
from baselines.common.device import resolve_device
from baselines.common.networks import TanhGaussianPolicy
from envs import env_spec, make_env
from replicate.demos import RULE_EXPERTS, Demonstrations, rollout_demos
from replicate.errors import DemoError, HarnessError
from replicate.store import provenance
from replicate.store.run_recorder import read_segments
from replicate.store.runner import (
    BEST_POLICY_FILE,
    PreparedRun,
    execute,
    execute_batch,
    prepare,
)
from replicate.store.spec import RunSpec

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


def expert_runs(
    env_id: str,
    steps: int,
    seeds: list[int],
    eval_interval: int,
    eval_episodes: int,
    algo: str,
    threads: int,
) -> list[PreparedRun]:
    """The expert runs of ``env_id``: one ordinary run per seed that keeps its best policy."""
    hyperparameters = {"keep_best_policy": True, "torch_threads": threads}
    return [
        prepare(RunSpec(algo, env_id, seed, steps, eval_interval, eval_episodes, hyperparameters))
        for seed in seeds
    ]


def train_expert(
    env_id: str,
    steps: int,
    seeds: list[int] | tuple[int, ...] = (0,),
    root: Path = Path("experts"),
    eval_interval: int = 10_000,
    eval_episodes: int = 5,
    checkpoint_interval: int = 10_000,
    on_steps: Callable[[int], None] = lambda n: None,
    algo: str | None = None,
    threads: int = 1,
    device: str = "auto",
    env_workers: int | None = None,
    time_limit_s: float | None = None,
) -> Path:
    """Train (or resume) one expert run per seed, several seeds as one seed batch, in the
    run store ``<root>/<env>/``; export the best policy any of them evaluated; return the
    exported file. With ``time_limit_s`` the training checkpoints and stops after that many
    seconds (the same call goes on from there), and the best policy so far is exported."""
    algo = _checked_request(env_id, steps, algo)
    seeds = list(seeds)
    if not seeds or len(set(seeds)) != len(seeds):
        raise HarnessError(
            f"expert seeds must be distinct, got {seeds}", "pass --seeds 1-8 or --seed N"
        )
    if threads < 1:
        raise HarnessError(f"thread count must be positive, got {threads}", "pass --threads 1")
    store = work_dir_for(env_id, root)
    runs = expert_runs(env_id, steps, seeds, eval_interval, eval_episodes, algo, threads)
    deadline = None if time_limit_s is None else time.time() + time_limit_s
    if env_workers is None:  # on a GPU the envs of a batch step in worker processes
        env_workers = 0 if resolve_device(device, True) == "cpu" or len(runs) == 1 else len(runs)
    try:
        if len(runs) == 1:
            execute(runs[0], store, on_steps, checkpoint_interval, device, deadline=deadline)
        else:
            outcome = execute_batch(
                runs,
                store,
                on_steps,
                checkpoint_interval,
                device,
                env_workers=env_workers,
                deadline=deadline,
            )
            for run_id, reason in outcome.failed:
                print(f"expert run {run_id} failed alone: {reason}")
    except TimeLimitReached:
        pass  # checkpointed where it stopped: the same command goes on from there
    return export_expert(env_id, root, [p.run_id for p in runs], time_limit_s)


@dataclass
class _ExpertCandidate:
    """An expert run, finished or in training, and the best policy it has kept."""

    path: Path
    spec: dict[str, Any]
    best: dict[str, Any]

    @property
    def curve(self) -> list[list[float]]:
        import pandas as pd

        curve = pd.read_csv(self.path / "curve.csv")
        return [[int(s), round(float(r), 3)] for s, r in zip(curve["step"], curve["return_mean"])]

    @property
    def segments(self) -> list[dict[str, Any]]:
        return read_segments(self.path)


def _candidates(store: Path, run_ids: list[str] | None) -> list[_ExpertCandidate]:
    """The expert runs in ``store`` (of ``run_ids`` where given) that have kept a policy."""
    found = []
    for path in sorted(store.glob("*")) if store.is_dir() else []:
        run_id = path.name.removeprefix(".partial-")
        if run_ids is not None and run_id not in run_ids:
            continue
        if (path / BEST_POLICY_FILE).is_file() and (path / "spec.json").is_file():
            best = torch.load(path / BEST_POLICY_FILE, weights_only=True, map_location="cpu")
            found.append(_ExpertCandidate(path, json.loads((path / "spec.json").read_text()), best))
    return found


def export_expert(
    env_id: str,
    root: Path = Path("experts"),
    run_ids: list[str] | None = None,
    time_limit_s: float | None = None,
) -> Path:
    """Write the best policy that the expert runs (``run_ids``, or every one in the expert
    store) evaluated so far, with its provenance, to the package's expert file."""
    store = work_dir_for(env_id, root)
    candidates = _candidates(store, run_ids)
    if not candidates:
        raise HarnessError(
            f"no expert training found in {store}",
            f"train one first: python -m replicate expert --env {env_id}",
        )
    chosen = max(candidates, key=lambda c: c.best["mean_return"])
    spec, best = chosen.spec, chosen.best
    algo, hyperparameters = spec["algo"], spec["hyperparameters"]
    seeds = sorted(c.spec["seed"] for c in candidates)
    threads = hyperparameters.get("torch_threads", 1)
    segments = chosen.segments
    device = segments[-1]["device"] if segments else "cpu"
    curve = chosen.curve
    command = f"python -m replicate expert --env {env_id} --steps {spec['total_steps']}"
    if len(seeds) > 1:
        command += f" --seeds {','.join(map(str, seeds))}"
    elif seeds != [0]:
        command += f" --seed {seeds[0]}"
    if time_limit_s:
        command += f" --minutes {time_limit_s / 60:g}"
    if algo != expert_algo_for(env_id):
        command += f" --algo {algo}"
    if threads != 1:
        command += f" --threads {threads}"
    # CPU training reproduces bit for bit; the command names the device it ran on
    command += " --device " + ("cuda" if device.startswith("cuda") else "cpu")
    metadata = {
        "env_id": env_id,
        "algo": algo,
        "seed": spec["seed"],
        "run_id": chosen.path.name.removeprefix(".partial-"),
        "hidden_sizes": list(hyperparameters["hidden_sizes"]),
        "hyperparameters": hyperparameters,
        "budget_steps": spec["total_steps"],
        "steps_trained": curve[-1][0],
        "best_step": int(best["step"]),
        "best_eval_return": float(best["mean_return"]),
        "wall_time_s": round(sum(s["wall_time_s"] for s in segments), 1),
        "curve": curve,
        "command": command,
        "git_revision": provenance.git_revision(),
        "device": device,
    }
    if len(candidates) > 1:  # a batch keeps its best member; every member's best, by seed
        metadata["batch_best_eval_return"] = {
            str(c.spec["seed"]): float(c.best["mean_return"]) for c in candidates
        }
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


EXPERT_RETURN_EPISODES = 10  # the expert's return is judged over at least this many episodes


def make_demos(env_id: str, n_pairs: int = 1000, seed: int = 0) -> Demonstrations:
    """Demonstrations for ``env_id`` from the harness's own experts: the paper's rule on
    MountainCar, elsewhere the committed SAC expert (this module)."""
    env_spec(env_id)  # unknown ids fail here with the list of known ones
    command = f"python -m replicate demos --env {env_id} --pairs {n_pairs} --seed {seed}"
    if env_id in RULE_EXPERTS:
        rule, description = RULE_EXPERTS[env_id]
        return rollout_demos(env_id, rule, n_pairs, seed, command, description)
    if not expert_path(env_id).is_file():
        raise DemoError(
            f"no expert is available yet to make demonstrations for {env_id}",
            "train one with `python -m replicate expert --env ENV` (see "
            "`nox -s experts`) or pass --demos with your own file",
        )
    expert = ExpertPolicy(env_id)
    meta = expert.metadata
    description = (
        f"deterministic policy of the harness's {meta['algo'].upper()} expert for "
        f"{meta['env_id']} (best evaluation {meta['best_eval_return']:.1f} at step "
        f"{meta['best_step']:,}; {meta['steps_trained']:,} env steps trained of a "
        f"{meta['budget_steps']:,}-step budget; published SAC experts train 1M)"
    )
    extra = {
        "expert_algo": meta["algo"],
        "expert_env_id": meta["env_id"],
        "expert_steps_trained": meta["steps_trained"],
        "expert_budget": meta["budget_steps"],
        "expert_file_command": meta["command"],
    }
    return rollout_demos(
        env_id,
        expert,
        n_pairs,
        seed,
        command,
        description,
        min_episodes=EXPERT_RETURN_EPISODES,
        extra_metadata=extra,
    )
