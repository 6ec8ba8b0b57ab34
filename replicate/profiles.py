"""Profiles (the budgets of a replication) and what a grid's training leaves: the data that
experiments, reports and the ablation share, kept apart so that reports need not import the
code that trains."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replicate.errors import HarnessError

if TYPE_CHECKING:  # the command line's help reads the profiles without loading torch
    from replicate.runner import Run


@dataclass(frozen=True)
class Profile:
    name: str
    steps: dict[str, int]  # per env
    eval_interval: dict[str, int]
    eval_episodes: int
    seeds: int
    overrides: dict[str, Any] = field(default_factory=dict)  # applied to every algorithm
    meaningful: bool = True
    summary: str = ""


# Budgets the paper states. Its text states none and its figures are missing from the
# source we have; the harness assumes 1M env steps on MuJoCo (the paper profile).
PAPER_BUDGETS: dict[str, str] = {
    "MountainCarContinuous-v0": "not stated in the text",
    **{
        env_id: "not stated in the text (assumed 1M)"
        for env_id in ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")
    },
}
PAPER_SEEDS_FIG3 = 3

PROFILES: dict[str, Profile] = {
    "smoke": Profile(
        "smoke",
        steps={"MountainCarContinuous-v0": 1200},
        eval_interval={"MountainCarContinuous-v0": 400},
        eval_episodes=1,
        seeds=2,
        overrides={
            "hidden_sizes": (32, 32),
            "batch_size": 32,
            "learning_starts": 400,
            "rollout_steps": 400,
            "bc_steps": 200,
        },
        meaningful=False,
        summary="seconds per run, tiny networks",
    ),
    "quick": Profile(
        "quick",
        steps={"MountainCarContinuous-v0": 20_000},
        eval_interval={"MountainCarContinuous-v0": 1000},
        eval_episodes=5,
        seeds=4,
        summary="MountainCar at 20,000 env steps with the paper's networks and "
        "hyperparameters; no MuJoCo claim is judged at this budget",
    ),
    # Between quick and paper (issue 14): every env at a budget where MuJoCo curves say
    # something (published SAC is at 40-100% of its 1M-step return by 200k); MountainCar's
    # runs are quick's (same specs), with a fifth seed.
    "reduced": Profile(
        "reduced",
        steps={
            "MountainCarContinuous-v0": 20_000,
            **{
                env_id: 200_000
                for env_id in ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")
            },
        },
        eval_interval={
            "MountainCarContinuous-v0": 1000,
            **{env_id: 5000 for env_id in ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")},
        },
        eval_episodes=5,
        seeds=5,
        summary="every env: MuJoCo at 200k env steps (Fig. 4: Ant at 500k), the paper's "
        "networks and hyperparameters; about 26M off-policy env steps, about 60 "
        "core-hours on CPU",
    ),
    "paper": Profile(
        "paper",
        steps={
            "MountainCarContinuous-v0": 100_000,
            **{
                env_id: 1_000_000
                for env_id in ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")
            },
        },
        eval_interval={
            "MountainCarContinuous-v0": 2000,
            **{
                env_id: 10_000
                for env_id in ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")
            },
        },
        eval_episodes=10,
        seeds=5,
        summary="1M env steps on MuJoCo (the paper's budget as assumed); meant for a "
        "cluster or a GPU machine",
    ),
}


def get_profile(name: str) -> Profile:
    if name not in PROFILES:
        raise HarnessError(
            f"unknown profile '{name}'; known profiles: {', '.join(PROFILES)}",
            f"pass --profile {', '.join(PROFILES)}",
        )
    return PROFILES[name]


def report_dir(profile: str, name: str) -> Path:
    """Where a report goes by default: ``reports/<name>`` for the quick profile (the default
    one), ``reports/<profile>/<name>`` for the others; the smoke profile's numbers mean
    nothing and are never committed."""
    return Path("reports") / name if profile == "quick" else Path("reports") / profile / name


@dataclass
class GridOutcome:
    runs: list[Run]
    failed: list[tuple[str, str]]  # (run id, reason)
    wall_time_s: float | None  # None: rebuilt from the store, nothing trained
    skipped: list[tuple[str, str, str]] = field(default_factory=list)  # (env, algo, reason)
