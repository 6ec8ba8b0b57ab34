"""The threshold ablation: how much DRL-EG's result depends on T2 (and on sigma).

The paper gives no value for the discriminator's threshold T2 or the guider's noise sigma.
This sweep trains DRL-EG over a grid of them, each point an optuna trial enqueued in one
study and trained on the Fig. 3 profile's seeds and budget, and reports final return and
area under the curve against T2 with bootstrap CIs. Two ends of the grid are checks as much as
settings: T2 = 0 switches guidance off, so its runs must equal SAC's run for run; a huge T2
guides every step while the gate is open.

Trials go through the run store, so a sweep that is stopped resumes where it stopped, and
several workers pointed at one optuna storage (any database URL optuna accepts) share the
grid; SQLite in the run store is the default.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from replicate.errors import HarnessError
from replicate.figures.ablation_grid import (
    ABLATION_ENV,
    MUJOCO_ABLATION_ENVS,
    MUJOCO_ABLATION_SEEDS,
    SIGMAS,
    Cell,
    ablation_report_name,
    ablation_specs,
    area_under_curve,
    default_thresholds,
    sac_specs,
)
from replicate.figures.ablation_report import write_ablation_report
from replicate.grids.drl_eg_settings import DEFAULT_GUIDE_NOISE_STD, T2_RULE_SETTINGS
from replicate.grids.experiments import GridOptions, run_grid
from replicate.grids.profiles import GridOutcome, get_profile, report_dir
from replicate.stats import stratified_bootstrap_ci
from replicate.store import query
from replicate.store.query import stored_runs
from replicate.store.runner import prepare

RULE_PROFILE = "reduced"  # the budget whose ablation fixes the MuJoCo rule
# Written before any reduced-budget ablation run had finished, and not to be changed after.
T2_RULE_CRITERION = (
    "For each T2 setting (1, 4, 16 and 64 times the env's demonstration-state spacing, and "
    "always), the gain of DRL-EG over SAC in area under the curve, seed by seed (the same "
    "seeds), divided by R_demo - R_random of the env (the demonstrations' mean return less "
    "that of uniformly random actions); averaged over the 3 seeds, then over Ant-v5 and "
    "Walker2d-v5 with equal weight. The MuJoCo rule is the setting with the largest mean "
    "gain, a tie going to the smaller T2, whatever the sign of that gain; it is chosen only "
    "when every setting has its 3 seeds on both envs."
)

REPORT_SEED = 20_260_102


def sweep_study_name(
    profile: str, env_id: str, n_seeds: int, grid_t2: list[float], grid_sigma: list[float]
) -> str:
    """The optuna study of a sweep: one per grid, since optuna fixes a parameter's choices
    within a study; the same name whether the sweep trains or its report is rebuilt."""
    grid_id = hashlib.sha256(json.dumps([grid_t2, grid_sigma]).encode()).hexdigest()[:8]
    return f"ablate-threshold-{profile}-{env_id}-s{n_seeds}-{grid_id}"


def t2_rule_gains(store: Path, profile: str = "reduced") -> dict[str, dict[str, list[float]]]:
    """For each setting of ``T2_RULE_SETTINGS`` and each MuJoCo ablation env, the normalised
    area-under-the-curve gains of DRL-EG over SAC per seed (``T2_RULE_CRITERION``), from
    the stored runs of the sweep's seeds."""
    from replicate.demos import default_demo_path, load_demos
    from replicate.figures.rlfd import random_return

    chosen = get_profile(profile)
    gains: dict[str, dict[str, list[float]]] = {setting: {} for setting in T2_RULE_SETTINGS}
    for env_id in MUJOCO_ABLATION_ENVS:
        if env_id not in chosen.steps or not default_demo_path(env_id).is_file():
            continue
        sac = {
            r.spec["seed"]: r
            for r in stored_runs(sac_specs(chosen, env_id, MUJOCO_ABLATION_SEEDS), store)
        }
        if not sac:
            continue
        scale = load_demos(default_demo_path(env_id), env_id).mean_return - random_return(env_id)
        for setting, threshold in zip(T2_RULE_SETTINGS, default_thresholds(profile, env_id)):
            runs = stored_runs(
                ablation_specs(
                    chosen, env_id, threshold, DEFAULT_GUIDE_NOISE_STD, MUJOCO_ABLATION_SEEDS
                ),
                store,
            )
            paired = sorted((r.spec["seed"], r) for r in runs if r.spec["seed"] in sac)
            if paired:
                gains[setting][env_id] = [
                    (area_under_curve(r) - area_under_curve(sac[seed])) / scale
                    for seed, r in paired
                ]
    return gains


def choose_t2_rule(
    gains: dict[str, dict[str, list[float]]],
    rng: np.random.Generator,
    envs: tuple[str, ...] = MUJOCO_ABLATION_ENVS,
    seeds: int = MUJOCO_ABLATION_SEEDS,
) -> dict[str, Any]:
    """``T2_RULE_CRITERION`` applied to ``gains`` (``t2_rule_gains``): per setting, the gain
    on each env and their mean with a stratified-bootstrap CI (seeds resampled within each
    env); the leader so far, and the choice once every setting has ``seeds`` seeds on every
    env (None before)."""
    rows = []
    for setting in T2_RULE_SETTINGS:
        per_env = gains.get(setting, {})
        row: dict[str, Any] = {
            "setting": setting,
            "per_env": {
                env: {"gain": float(np.mean(per_env[env])), "n": len(per_env[env])}
                for env in envs
                if per_env.get(env)
            },
            "gain": float("nan"),
            "low": float("nan"),
            "high": float("nan"),
            "complete": all(len(per_env.get(env, [])) >= seeds for env in envs),
        }
        if len(row["per_env"]) == len(envs):
            row["gain"] = float(np.mean([row["per_env"][env]["gain"] for env in envs]))
        if row["complete"]:
            matrix = np.array([per_env[env][:seeds] for env in envs]).T  # (seeds, envs)
            est = stratified_bootstrap_ci(lambda m: m.mean(axis=0).mean(), (matrix,), rng)
            row["gain"], row["low"], row["high"] = (
                float(est.value),
                float(est.low),
                float(est.high),
            )
        rows.append(row)
    scored = [r for r in rows if not math.isnan(r["gain"])]
    # max() keeps the first of equal values: the smaller T2 wins a tie
    leader = max(scored, key=lambda r: r["gain"])["setting"] if scored else None
    complete = all(r["complete"] for r in rows)
    return {
        "criterion": T2_RULE_CRITERION,
        "envs": list(envs),
        "seeds": seeds,
        "rows": rows,
        "complete": complete,
        "leader": leader,
        "choice": leader if complete else None,
    }


def run_threshold_ablation(
    profile: str = "quick",
    seeds: int | None = None,
    store: Path = Path("runs"),
    out_dir: Path | None = None,
    storage: str | None = None,
    thresholds: list[float] | None = None,
    sigmas: list[float] | None = None,
    env_id: str = ABLATION_ENV,
    options: GridOptions = GridOptions(),
) -> Path | None:
    """Run (or finish) the sweep and write its report; return the report's path (None with
    ``dry_run``: print what would train, from one machine, and touch nothing)."""
    chosen = get_profile(profile)
    if env_id not in chosen.steps:
        raise HarnessError(
            f"profile '{profile}' has no budget for {env_id}", f"pick one of {sorted(chosen.steps)}"
        )
    default_seeds = MUJOCO_ABLATION_SEEDS if env_id in MUJOCO_ABLATION_ENVS else chosen.seeds
    n_seeds = default_seeds if seeds is None else seeds
    if n_seeds <= 0:
        raise HarnessError(f"number of seeds must be positive, got {n_seeds}", "pass --seeds 3")
    grid_t2 = sorted(thresholds if thresholds is not None else default_thresholds(profile, env_id))
    grid_sigma = sorted(sigmas if sigmas is not None else SIGMAS[profile])
    if any(t < 0 for t in grid_t2) or any(s < 0 for s in grid_sigma):
        raise HarnessError("thresholds and sigmas must be >= 0", "pass values like 0 0.05 0.2")
    store = Path(store)
    if options.dry_run:
        everything = sac_specs(chosen, env_id, n_seeds) + [
            spec
            for threshold in grid_t2
            for sigma in grid_sigma
            for spec in ablation_specs(chosen, env_id, threshold, sigma, n_seeds)
        ]
        run_grid(everything, store, options)
        return None
    import optuna

    store.mkdir(parents=True, exist_ok=True)
    shared_study = storage is not None
    storage = storage or f"sqlite:///{(store / 'ablate-threshold.db').resolve()}"
    out_dir = Path(out_dir or report_dir(profile, ablation_report_name(env_id)))

    for threshold in grid_t2:  # input errors (demonstrations, values) surface before training
        for sigma in grid_sigma:
            for spec in ablation_specs(chosen, env_id, threshold, sigma, n_seeds):
                prepare(spec)

    # SAC on the same seeds (what T2 = 0 must reproduce exactly) and, on one machine, the
    # whole grid in the same call: workers train points side by side, and with --batch the
    # points' runs share batches (T2 and sigma are per member); the trials below then record
    # what is stored. With --storage, machines sharing the study take its points one by one.
    sac = sac_specs(chosen, env_id, n_seeds)
    sweep = (
        []
        if shared_study
        else [
            spec
            for threshold in grid_t2
            for sigma in grid_sigma
            for spec in ablation_specs(chosen, env_id, threshold, sigma, n_seeds)
        ]
    )
    trained = run_grid(sac + sweep, store, options)
    failed = list(trained.failed)
    failed_ids = {run_id for run_id, _ in failed}
    sac_ids = {prepare(spec).run_id for spec in sac}
    sac_outcome = GridOutcome(stored_runs(sac, store), [f for f in failed if f[0] in sac_ids], None)

    def objective(trial: Any) -> float:
        threshold = trial.suggest_categorical("guide_threshold", grid_t2)
        sigma = trial.suggest_categorical("guide_noise_std", grid_sigma)
        specs = [
            s
            for s in ablation_specs(chosen, env_id, threshold, sigma, n_seeds)
            if prepare(s).run_id not in failed_ids
        ]  # a failure is not retrained at once
        outcome = run_grid(specs, store, options)
        failed.extend(outcome.failed)
        if not outcome.runs:
            raise HarnessError(
                f"every run failed at T2 = {threshold}, sigma = {sigma}",
                "see the reasons printed above",
            )
        trial.set_user_attr("run_ids", [r.path.name for r in outcome.runs])
        trial.set_user_attr("auc_mean", float(np.mean([area_under_curve(r) for r in outcome.runs])))
        return float(np.mean([r.final_return for r in outcome.runs]))

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study_name = sweep_study_name(profile, env_id, n_seeds, grid_t2, grid_sigma)
    # Every trial is enqueued with its grid point, so the sampler never chooses (optuna's
    # grid sampler would count failed or interrupted trials as visited, and stop the study).
    study = optuna.create_study(
        study_name=study_name,
        storage=storage,
        load_if_exists=True,
        direction="maximize",
        sampler=optuna.samplers.RandomSampler(seed=0),
    )
    # The store, not the study, is the record: a point is done when its runs are stored.
    remaining = [
        (t, s)
        for t in grid_t2
        for s in grid_sigma
        if len(stored_runs(ablation_specs(chosen, env_id, t, s, n_seeds), store)) < n_seeds
    ]
    waiting = optuna.trial.TrialState.WAITING
    queued = {
        tuple(
            t.system_attrs.get("fixed_params", {}).get(k)
            for k in ("guide_threshold", "guide_noise_std")
        )
        for t in study.get_trials(deepcopy=False, states=(waiting,))
    }
    for threshold, sigma in remaining:
        if (threshold, sigma) not in queued:  # another worker's queue is shared, not doubled
            study.enqueue_trial({"guide_threshold": threshold, "guide_noise_std": sigma})
    while study.get_trials(deepcopy=False, states=(waiting,)):
        trial = study.ask()  # takes the oldest queued point, atomically in the storage
        try:
            value = objective(trial)
        except HarnessError as exc:
            print(f"grid point {trial.params} failed: {exc}", flush=True)
            study.tell(trial, state=optuna.trial.TrialState.FAIL)
            continue
        study.tell(trial, value)

    # The report reads the run store, not the study: every number traces to run directories.
    cells = []
    for threshold in grid_t2:
        for sigma in grid_sigma:
            specs = ablation_specs(chosen, env_id, threshold, sigma, n_seeds)
            cells.append(Cell(threshold, sigma, stored_runs(specs, store)))
    stored = {r.path.name for c in cells for r in c.runs} | {r.path.name for r in sac_outcome.runs}
    failed = [f for f in failed if f[0] not in stored]  # another worker may have finished it
    return write_ablation_report(
        cells,
        sac_outcome,
        chosen,
        env_id,
        study_name,
        storage,
        failed,
        out_dir,
        t2_rule_standing(env_id, store, profile),
    )


def t2_rule_standing(env_id: str, store: Path, profile: str) -> dict[str, Any] | None:
    """Where the MuJoCo T2 rule stands on the store's runs of this profile (None for
    MountainCar); only the reduced profile's standing fixes the rule."""
    if env_id not in MUJOCO_ABLATION_ENVS:
        return None
    standing = choose_t2_rule(
        t2_rule_gains(Path(store), profile), np.random.default_rng(REPORT_SEED + 1)
    )
    return dict(standing, profile=profile, fixes_the_rule=profile == RULE_PROFILE)


def rebuild_threshold_ablation(
    profile: str = "quick",
    store: Path = Path("runs"),
    out_dir: Path | None = None,
    env_id: str = ABLATION_ENV,
    storage: str | None = None,
) -> Path | None:
    """Write the ablation report from the store alone: every (T2, sigma) point whose DRL-EG
    runs at the profile's budget are there, over the seeds found. Returns None, writing
    nothing, when the store holds none (a committed report stays)."""
    from replicate.claims.confirm_judge import SEED_BLOCK

    chosen = get_profile(profile)
    store = Path(store)
    points: dict[tuple[float, float], int] = {}
    steps = chosen.steps.get(env_id)
    drl_eg = query.Cell("drl-eg", env_id, steps, seeds=(0, SEED_BLOCK))
    for run in query.find_runs(store, drl_eg) if steps is not None else []:
        hyper = run.spec["hyperparameters"]
        key = (hyper["guide_threshold"], hyper["guide_noise_std"])
        points[key] = max(points.get(key, 0), run.spec["seed"] + 1)
    # as many seeds as the sweep trains: Fig. 3's DRL-EG runs share the 1x point's spec on
    # more seeds, and would otherwise give that point more seeds than the others
    sweep_seeds = MUJOCO_ABLATION_SEEDS if env_id in MUJOCO_ABLATION_ENVS else chosen.seeds
    n_seeds = min(max(points.values(), default=0), sweep_seeds)
    cells = [
        Cell(t, s, stored_runs(ablation_specs(chosen, env_id, t, s, n_seeds), store))
        for t, s in sorted(points)
    ]
    cells = [c for c in cells if c.runs]  # runs of other settings than the sweep's own
    if not cells:
        return None
    sac_outcome = GridOutcome(stored_runs(sac_specs(chosen, env_id, n_seeds), store), [], None)
    storage = storage or f"sqlite:///{(store / 'ablate-threshold.db').resolve()}"
    out_dir = Path(out_dir or report_dir(profile, ablation_report_name(env_id)))
    return write_ablation_report(
        cells,
        sac_outcome,
        chosen,
        env_id,
        sweep_study_name(
            profile, env_id, n_seeds, sorted({t for t, _ in points}), sorted({s for _, s in points})
        ),
        storage,
        [],
        out_dir,
        t2_rule_standing(env_id, store, profile),
    )
