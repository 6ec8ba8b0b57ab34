"""Profiles (the budgets of a replication) and what a grid's training leaves: the data that
experiments, reports and the ablation share, kept apart so that reports need not import the
code that trains."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replicate.errors import HarnessError

if TYPE_CHECKING:  # the command line's help reads the profiles without loading torch
    from replicate.store.runner import Run


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

MOUNTAINCAR = "MountainCarContinuous-v0"
MUJOCO = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")
CARTPOLE_SPARSE = "dm_control/cartpole-swingup_sparse-v0"
BALL_IN_CUP = "dm_control/ball_in_cup-catch-v0"

# Every figure's budget per profile, in one table: (env steps, evaluation interval) per env.
# Fig. 3 (and the threshold ablations, which sweep its cells): between quick and paper,
# reduced trains every env at a budget where MuJoCo curves say something (published SAC is
# at 40-100% of its 1M-step return by 200k), MountainCar's runs being quick's with a fifth
# seed. Fig. 4: Ant alone. The comparison: MountainCar's budgets match Fig. 3's, so its SAC,
# DRL-EG and DDPGfD runs are shared; the sparse dm-control budgets are those their dense
# experts needed (cartpole 40k steps, ball-in-cup 20k) with room to spare.
BUDGETS: dict[str, dict[str, dict[str, tuple[int, int]]]] = {
    "fig3": {
        "smoke": {MOUNTAINCAR: (1200, 400)},
        "quick": {MOUNTAINCAR: (20_000, 1000)},
        "reduced": {MOUNTAINCAR: (20_000, 1000), **{e: (200_000, 5000) for e in MUJOCO}},
        "paper": {MOUNTAINCAR: (100_000, 2000), **{e: (1_000_000, 10_000) for e in MUJOCO}},
    },
    "fig4": {
        "smoke": {"Ant-v5": (1200, 400)},
        "quick": {"Ant-v5": (20_000, 1000)},
        "reduced": {"Ant-v5": (500_000, 10_000)},
        "paper": {"Ant-v5": (1_000_000, 10_000)},
    },
    "rlfd": {
        "smoke": {MOUNTAINCAR: (1200, 400)},
        "quick": {MOUNTAINCAR: (20_000, 1000)},
        "reduced": {
            MOUNTAINCAR: (20_000, 1000),
            CARTPOLE_SPARSE: (50_000, 5000),
            BALL_IN_CUP: (50_000, 5000),
            "Hopper-v5": (200_000, 5000),
            "Ant-v5": (200_000, 5000),
        },
        "paper": {
            MOUNTAINCAR: (100_000, 2000),
            CARTPOLE_SPARSE: (200_000, 10_000),
            BALL_IN_CUP: (200_000, 10_000),
            "Hopper-v5": (1_000_000, 10_000),
            "Ant-v5": (1_000_000, 10_000),
        },
    },
}


def _fig3(profile: str) -> dict[str, dict[str, int]]:
    table = BUDGETS["fig3"][profile]
    return {
        "steps": {e: s for e, (s, _) in table.items()},
        "eval_interval": {e: i for e, (_, i) in table.items()},
    }


PROFILES: dict[str, Profile] = {
    "smoke": Profile(
        "smoke",
        **_fig3("smoke"),
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
        **_fig3("quick"),
        eval_episodes=5,
        seeds=4,
        summary="MountainCar at 20,000 env steps with the paper's networks and "
        "hyperparameters; no MuJoCo claim is judged at this budget",
    ),
    "reduced": Profile(
        "reduced",
        **_fig3("reduced"),
        eval_episodes=5,
        seeds=5,
        summary="every env: MuJoCo at 200k env steps (Fig. 4: Ant at 500k), the paper's "
        "networks and hyperparameters; about 26M off-policy env steps, 70 to 100 "
        "core hours on CPU (75 to 110 env steps/s per core in seed batches)",
    ),
    "paper": Profile(
        "paper",
        **_fig3("paper"),
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
