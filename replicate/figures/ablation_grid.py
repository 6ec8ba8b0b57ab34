"""The threshold ablation's grid: the T2 and sigma values it sweeps per profile and env (on
MuJoCo in multiples of the env's demonstration-state spacing), its run specs and cells, and
the area under the curve it reports beside the final return."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from replicate.grids.drl_eg_settings import ALWAYS_GUIDE, SPACING_MULTIPLES, drl_eg_env_defaults
from replicate.grids.profiles import Profile
from replicate.grids.train import algorithm_overrides
from replicate.store.runs import Run
from replicate.store.spec import RunSpec

ALWAYS = ALWAYS_GUIDE
THRESHOLDS: dict[str, list[float]] = {  # MountainCar's grid, absolute values
    "smoke": [0.0, 0.05, ALWAYS],
    "quick": [0.0, 0.01, 0.05, 0.2, ALWAYS],
    "reduced": [0.0, 0.01, 0.05, 0.2, ALWAYS],
    "paper": [0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, ALWAYS],
}
SIGMAS: dict[str, list[float]] = {
    "smoke": [0.1],
    "quick": [0.1],
    "reduced": [0.1],
    "paper": [0.05, 0.1, 0.3],
}
ABLATION_ENV = "MountainCarContinuous-v0"  # where guidance decides the outcome (claim 1)
# On MuJoCo T2 is swept in multiples of the env's default, the median spacing of its
# demonstration states (which admits about 0.5% of an untrained Ant's states), plus always,
# on fewer seeds than Fig. 3: 3 seeds x 5 points x 2 envs is already 6M env steps at 200k.
MUJOCO_ABLATION_ENVS = ("Ant-v5", "Walker2d-v5")
MUJOCO_ABLATION_SEEDS = 3


def threshold_spacing(env_id: str) -> float | None:
    """The unit of the env's T2 grid: its median demonstration-state spacing (MuJoCo), or
    None where T2 is swept in absolute values (MountainCar)."""
    if env_id not in MUJOCO_ABLATION_ENVS:
        return None
    return drl_eg_env_defaults(env_id)["guide_threshold"]


def default_thresholds(profile: str, env_id: str) -> list[float]:
    spacing = threshold_spacing(env_id)
    if spacing is None:
        return list(THRESHOLDS[profile])
    return [m * spacing for m in SPACING_MULTIPLES] + [ALWAYS]


def ablation_report_name(env_id: str) -> str:
    """``ablate-threshold`` for MountainCar (the first sweep), ``ablate-threshold-<env>``
    for the others."""
    if env_id == ABLATION_ENV:
        return "ablate-threshold"
    return "ablate-threshold-" + env_id.split("/")[-1].split("-v")[0].lower()


@dataclass
class Cell:
    """The runs of one (T2, sigma) point of the grid."""

    threshold: float
    sigma: float
    runs: list[Run]


def threshold_label(threshold: float, spacing: float | None = None) -> str:
    if threshold == 0:
        return "0 (off)"
    if threshold >= ALWAYS:
        return "always"
    if spacing:
        return f"{threshold / spacing:.3g}x spacing ({threshold:.3g})"
    return f"{threshold:g}"


def ablation_specs(
    profile: Profile, env_id: str, threshold: float, sigma: float, seeds: int
) -> list[RunSpec]:
    hyper = algorithm_overrides("drl-eg", profile.overrides)
    hyper.update(drl_eg_env_defaults(env_id))
    hyper.update(guide_threshold=float(threshold), guide_noise_std=float(sigma))
    return _seed_specs("drl-eg", profile, env_id, seeds, hyper)


def sac_specs(profile: Profile, env_id: str, seeds: int) -> list[RunSpec]:
    return _seed_specs("sac", profile, env_id, seeds, algorithm_overrides("sac", profile.overrides))


def _seed_specs(algo: str, profile: Profile, env_id: str, seeds: int, hyper: dict) -> list[RunSpec]:
    """Seeds 0..seeds-1 of ``algo`` on ``env_id`` at the profile's budget."""
    steps, interval = profile.steps[env_id], profile.eval_interval[env_id]
    return [
        RunSpec(algo, env_id, seed, steps, interval, profile.eval_episodes, dict(hyper))
        for seed in range(seeds)
    ]


def area_under_curve(run: Run) -> float:
    """Mean evaluation return over the run, trapezoids over env steps: one number that
    rewards learning early as well as ending high."""
    steps = run.curve["step"].to_numpy(float)
    returns = run.curve["return_mean"].to_numpy(float)
    return float(np.trapezoid(returns, steps) / (steps[-1] - steps[0]))
