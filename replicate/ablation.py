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

import base64
import hashlib
import json
import math
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from replicate import drl_eg_settings
from replicate.drl_eg_settings import (
    ALWAYS_GUIDE,
    DEFAULT_GUIDE_NOISE_STD,
    SPACING_MULTIPLES,
    T2_RULE_SETTINGS,
    drl_eg_env_defaults,
)
from replicate.errors import HarnessError
from replicate.experiments import run_grid
from replicate.grids import algorithm_overrides, stored_runs
from replicate.profiles import GridOutcome, Profile, get_profile, report_dir
from replicate.provenance import portable_path
from replicate.runner import DEFAULT_CHECKPOINT_INTERVAL, Run, prepare
from replicate.spec import RunSpec
from replicate.stats import stratified_bootstrap_ci, t_mean
from replicate.templating import report_environment

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


def admitted_share(
    env_id: str, thresholds: list[float], episodes: int = 5, seed: int = 0, max_states: int = 5000
) -> list[float]:
    """For each T2, the share of the states that uniformly random actions visit (``episodes``
    seeded episodes, at most ``max_states`` states) lying within T2 of a demonstration state:
    how much an untrained agent would be guided, before any training."""
    from scipy.spatial import cKDTree

    from envs import make_env
    from replicate.demos import default_demo_path, load_demos

    demos = load_demos(default_demo_path(env_id), env_id)
    env = make_env(env_id, seed=seed)
    env.action_space.seed(seed)
    states = []
    for _ in range(episodes):
        obs, _ = env.reset()
        done = False
        while not done and len(states) < max_states:
            states.append(obs)
            obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated
    env.close()
    distances, _ = cKDTree(demos.observations.astype(np.float64)).query(
        np.asarray(states, dtype=np.float64)
    )
    return [float(np.mean(distances <= t)) if t > 0 else 0.0 for t in thresholds]


def ablation_report_name(env_id: str) -> str:
    """``ablate-threshold`` for MountainCar (the first sweep), ``ablate-threshold-<env>``
    for the others."""
    if env_id == ABLATION_ENV:
        return "ablate-threshold"
    return "ablate-threshold-" + env_id.split("/")[-1].split("-v")[0].lower()


REPORT_SEED = 20_260_102


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
    return [
        RunSpec(
            "drl-eg",
            env_id,
            seed,
            profile.steps[env_id],
            profile.eval_interval[env_id],
            profile.eval_episodes,
            hyper,
        )
        for seed in range(seeds)
    ]


def sac_specs(profile: Profile, env_id: str, seeds: int) -> list[RunSpec]:
    hyper = algorithm_overrides("sac", profile.overrides)
    return [
        RunSpec(
            "sac",
            env_id,
            seed,
            profile.steps[env_id],
            profile.eval_interval[env_id],
            profile.eval_episodes,
            hyper,
        )
        for seed in range(seeds)
    ]


def t2_rule_gains(store: Path, profile: str = "reduced") -> dict[str, dict[str, list[float]]]:
    """For each setting of ``T2_RULE_SETTINGS`` and each MuJoCo ablation env, the normalised
    area-under-the-curve gains of DRL-EG over SAC per seed (``T2_RULE_CRITERION``), from
    the stored runs of the sweep's seeds."""
    from replicate.demos import default_demo_path, load_demos
    from replicate.rlfd import random_return

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


def area_under_curve(run: Run) -> float:
    """Mean evaluation return over the run, trapezoids over env steps: one number that
    rewards learning early as well as ending high."""
    steps = run.curve["step"].to_numpy(float)
    returns = run.curve["return_mean"].to_numpy(float)
    return float(np.trapezoid(returns, steps) / (steps[-1] - steps[0]))


def run_threshold_ablation(
    profile: str = "quick",
    seeds: int | None = None,
    store: Path = Path("runs"),
    out_dir: Path | None = None,
    storage: str | None = None,
    workers: int | None = None,
    thresholds: list[float] | None = None,
    sigmas: list[float] | None = None,
    env_id: str = ABLATION_ENV,
    checkpoint_interval: int = DEFAULT_CHECKPOINT_INTERVAL,
    executor: str = "local",
    address: str | None = None,
    device: str = "auto",
    gpu_workers: int | None = None,
    batch: int | None = None,
    dry_run: bool = False,
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
    if dry_run:
        everything = sac_specs(chosen, env_id, n_seeds) + [
            spec
            for threshold in grid_t2
            for sigma in grid_sigma
            for spec in ablation_specs(chosen, env_id, threshold, sigma, n_seeds)
        ]
        run_grid(
            everything,
            store,
            workers,
            checkpoint_interval,
            executor,
            address,
            device,
            gpu_workers,
            batch,
            dry_run=True,
        )
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
    trained = run_grid(
        sac + sweep,
        store,
        workers,
        checkpoint_interval,
        executor,
        address,
        device,
        gpu_workers,
        batch,
    )
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
        outcome = run_grid(
            specs,
            store,
            workers,
            checkpoint_interval,
            executor,
            address,
            device,
            gpu_workers,
            batch,
        )
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
    # one study per grid: optuna fixes a parameter's choices within a study
    grid_id = hashlib.sha256(json.dumps([grid_t2, grid_sigma]).encode()).hexdigest()[:8]
    study_name = f"ablate-threshold-{profile}-{env_id}-s{n_seeds}-{grid_id}"
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


def zero_threshold_equals_sac(cells: list[Cell], sac_runs: list[Run]) -> dict[str, Any] | None:
    """Compare every T2 = 0 run with the SAC run of its seed, curve for curve."""
    zero_runs = [r for c in cells if c.threshold == 0 for r in c.runs]
    if not zero_runs or not sac_runs:
        return None
    by_seed = {r.spec["seed"]: r for r in sac_runs}
    pairs = [(r, by_seed[r.spec["seed"]]) for r in zero_runs if r.spec["seed"] in by_seed]
    equal = [r.curve["returns"].tolist() == s.curve["returns"].tolist() for r, s in pairs]
    return {"pairs": len(pairs), "equal": int(sum(equal)), "holds": bool(pairs) and all(equal)}


def t2_shades(n: int) -> list[Any]:
    """``n`` shades of DRL-EG's colour, light to dark: its settings in the ablation figures
    (SAC keeps its own colour there)."""
    import seaborn as sns

    from replicate.figures import algo_color

    if n == 1:
        return [algo_color("drl-eg")]
    return sns.blend_palette(["#f4b183", algo_color("drl-eg"), "#3d1500"], n)


def tick_label(label: str) -> str:
    """A T2 setting's label as a short tick on two lines ('4x' over '(2.6)'; the axis label
    says what the multiple is of), so that neighbouring ticks stay apart."""
    return label.replace(" spacing (", "\n(").replace(" (", "\n(")


def _figure(rows: list[dict[str, Any]], sac_final: float | None, sac_auc: float | None) -> bytes:
    from matplotlib.lines import Line2D

    from replicate.figures import algo_color, panel_grid, png_bytes, set_theme, shared_legend

    set_theme()
    sigmas = sorted({r["sigma"] for r in rows})
    labels = list(dict.fromkeys(r["label"] for r in rows))
    shades = dict(zip(sigmas, t2_shades(len(sigmas)), strict=True))
    fig, axes, _ = panel_grid(2, 2, 4.0, legend_height=0.6)
    for ax, key, reference, name in (
        (axes[0], "final", sac_final, "final return"),
        (axes[1], "auc", sac_auc, "area under the curve"),
    ):
        for i, sigma in enumerate(sigmas):
            xs, ys, lows, highs = [], [], [], []
            for r in rows:
                if r["sigma"] == sigma and not math.isnan(r[key]["mean"]):
                    xs.append(labels.index(r["label"]) + (i - (len(sigmas) - 1) / 2) * 0.08)
                    ys.append(r[key]["mean"])
                    lows.append(r[key]["mean"] - r[key]["low"] if r[key]["n"] > 1 else 0)
                    highs.append(r[key]["high"] - r[key]["mean"] if r[key]["n"] > 1 else 0)
            ax.errorbar(
                xs,
                ys,
                yerr=[lows, highs],
                fmt="o-",
                capsize=3,
                color=shades[sigma],
                linewidth=1.8,
                markersize=6,
            )
        if reference is not None:
            ax.axhline(reference, color=algo_color("sac"), linestyle="--", linewidth=1.5)
        ax.set_xticks(range(len(labels)), [tick_label(label) for label in labels])
        ax.set_xlabel(
            "discriminator threshold T2"
            + (
                ": multiple of the spacing (value)"
                if any(" spacing (" in label for label in labels)
                else ""
            )
        )
        ax.set_ylabel(name)
    handles = [Line2D([], [], color=shades[s], marker="o", linewidth=1.8) for s in sigmas]
    names = [f"DRL-EG, sigma = {s:g} (mean over seeds, t-interval)" for s in sigmas]
    if sac_final is not None or sac_auc is not None:
        handles.append(Line2D([], [], color=algo_color("sac"), linestyle="--", linewidth=1.5))
        names.append("SAC (mean over seeds)")
    shared_legend(fig, handles, names, columns=min(len(names), 3))
    return png_bytes(fig)


def _mean_curve(runs: list[Run], column: str) -> tuple[np.ndarray, np.ndarray]:
    """Steps and the mean of ``column`` over ``runs`` at the steps every run reached."""
    length = min(len(r.curve) for r in runs)
    steps = runs[0].curve["step"].to_numpy(float)[:length]
    values = np.stack([r.curve[column].to_numpy(float)[:length] for r in runs])
    if column not in ("guided_fraction", "train_return"):
        return steps, values.mean(axis=0)
    with warnings.catch_warnings():  # a point no run has a value for stays NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        return steps, np.nanmean(values, axis=0)


def _curves_figure(cells: list[Cell], sac_runs: list[Run], spacing: float | None) -> bytes:
    """Return and guided fraction of training steps against env steps, one line per T2
    (the first sigma of the grid), beside SAC's return; dotted, where the runs recorded it,
    what the training episodes (the executed actions, a guider's included) earned."""
    from matplotlib.lines import Line2D

    from replicate.figures import (
        algo_color,
        format_steps_axis,
        panel_grid,
        png_bytes,
        set_theme,
        shared_legend,
    )

    set_theme()
    first_sigma = min((c.sigma for c in cells), default=0.0)
    shown = [c for c in cells if c.sigma == first_sigma and c.runs]
    colors = t2_shades(max(len(shown), 1))
    fig, (left, right), _ = panel_grid(2, 2, 3.9, legend_height=1.0)
    dotted = False

    def dotted_training_returns(runs: list[Run], color: Any) -> bool:
        steps, earned = _mean_curve(runs, "train_return")
        if np.isfinite(earned).any():
            left.plot(steps, earned, color=color, linestyle=":", linewidth=1.3)
            return True
        return False

    handles, names = [], []
    for color, cell in zip(colors, shown):
        left.plot(*_mean_curve(cell.runs, "return_mean"), color=color, linewidth=2)
        dotted |= dotted_training_returns(cell.runs, color)
        right.plot(*_mean_curve(cell.runs, "guided_fraction"), color=color, linewidth=2)
        handles.append(Line2D([], [], color=color, linewidth=2))
        names.append(f"T2 = {threshold_label(cell.threshold, spacing)}")
    if sac_runs:
        sac = algo_color("sac")
        left.plot(*_mean_curve(sac_runs, "return_mean"), color=sac, linestyle="--", linewidth=1.8)
        dotted |= dotted_training_returns(sac_runs, sac)
        handles.append(Line2D([], [], color=sac, linestyle="--", linewidth=1.8))
        names.append("SAC")
    format_steps_axis(left)
    left.set_ylabel("return (mean over seeds)")
    left.set_title(
        "solid: deterministic evaluation" + ("; dotted: training episodes" if dotted else ""),
        fontsize=11,
    )
    format_steps_axis(right)
    right.set_ylabel("guided share of training steps")
    right.set_ylim(-0.02, 1.02)
    right.set_title("share of training steps the guider took", fontsize=11)
    shared_legend(fig, handles, names, columns=min(len(names), 4))
    return png_bytes(fig)


def t2_rule_standing(env_id: str, store: Path, profile: str) -> dict[str, Any] | None:
    """Where the MuJoCo T2 rule stands on the store's runs of this profile (None for
    MountainCar); only the reduced profile's standing fixes the rule."""
    if env_id not in MUJOCO_ABLATION_ENVS:
        return None
    standing = choose_t2_rule(
        t2_rule_gains(Path(store), profile), np.random.default_rng(REPORT_SEED + 1)
    )
    return dict(standing, profile=profile, fixes_the_rule=profile == RULE_PROFILE)


def _shown_path(path: str) -> str:
    """``path`` relative to the working directory when inside it (a report rebuilt in another
    checkout names no directory of this machine), else relative to the project if it can be."""
    try:
        return Path(path).resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return portable_path(path)


def write_ablation_report(
    cells: list[Cell],
    sac_outcome: GridOutcome,
    profile: Profile,
    env_id: str,
    study_name: str,
    storage: str,
    failed: list[tuple[str, str]],
    out_dir: Path,
    t2_rule: dict[str, Any] | None = None,
) -> Path:
    from replicate import provenance
    from replicate.report import _atomic_write, mujoco_threats, summary_bytes

    def estimate(values: list[float]) -> dict[str, Any]:
        if not values:
            return {"mean": float("nan"), "low": float("nan"), "high": float("nan"), "n": 0}
        est = t_mean(np.array(values))
        return {
            "mean": est.value,
            "low": est.low,
            "high": est.high,
            "n": len(values),
            "method": est.label,
        }

    spacing = threshold_spacing(env_id)
    admitted = admitted_share(env_id, [c.threshold for c in cells])
    rows = [
        {
            "threshold": c.threshold,
            "sigma": c.sigma,
            "label": threshold_label(c.threshold, spacing),
            "admitted_random_share": share,
            "final": estimate([r.final_return for r in c.runs]),
            "auc": estimate([area_under_curve(r) for r in c.runs]),
            "guided_share": [r.guided_share for r in c.runs],
            "runs": [r.path.name for r in c.runs],
        }
        for c, share in zip(cells, admitted)
    ]
    sac_runs = sac_outcome.runs
    sac_final = float(np.mean([r.final_return for r in sac_runs])) if sac_runs else None
    sac_auc = float(np.mean([area_under_curve(r) for r in sac_runs])) if sac_runs else None
    context = {
        "title": f"Threshold ablation on {env_id}, profile '{profile.name}'",
        "profile": profile,
        "env_id": env_id,
        "rows": rows,
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "figure_png_b64": base64.b64encode(_figure(rows, sac_final, sac_auc)).decode(),
        "curves_png_b64": base64.b64encode(_curves_figure(cells, sac_runs, spacing)).decode(),
        "spacing": spacing,
        "zero_check": zero_threshold_equals_sac(cells, sac_runs),
        "sac_final": sac_final,
        "steps": profile.steps[env_id],
        "study_name": study_name,
        "storage": (
            _shown_path(storage.split("///")[-1])
            if storage.startswith("sqlite")
            else "(database URL)"
        ),
        "failed": failed,
        "always": ALWAYS,
        "sac_runs": [r.path.name for r in sac_runs],
        "revisions": sorted(
            {r.provenance["git_revision"] for c in cells for r in c.runs}
            | {provenance.git_revision()}
        ),
        "t2_rule": t2_rule,
        "rule_in_force": drl_eg_settings.MUJOCO_T2_RULE,
        # under every T2 of the sweep, so no single guided share stands for it
        "threats": mujoco_threats([r for c in cells for r in c.runs] + sac_runs, guidance=False),
    }
    environment = report_environment()
    html = environment.get_template("ablation.html").render(**context)
    out_dir = Path(out_dir)
    _atomic_write(out_dir / "index.html", html.encode())
    summary = {
        "profile": profile.name,
        "env_id": env_id,
        "spacing": spacing,
        "rows": rows,
        "zero_threshold_equals_sac": context["zero_check"],
        "sac_final_mean": sac_final,
        "sac_runs": context["sac_runs"],
        "run_ids": [run for row in rows for run in row["runs"]] + context["sac_runs"],
        "failed": [{"run_id": i, "reason": why} for i, why in failed],
        "t2_rule": t2_rule,
        "steps": context["steps"],
        "threats": context["threats"],
        "generated": context["generated"],
    }
    _atomic_write(out_dir / "summary.json", summary_bytes(summary))
    return out_dir / "index.html"


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
    from replicate.runner import completed_runs

    chosen = get_profile(profile)
    store = Path(store)
    points: dict[tuple[float, float], int] = {}
    for run in completed_runs(store):
        spec = run.spec
        if (
            spec["algo"] == "drl-eg"
            and spec["env_id"] == env_id
            and spec["total_steps"] == chosen.steps.get(env_id)
        ):
            key = (
                spec["hyperparameters"]["guide_threshold"],
                spec["hyperparameters"]["guide_noise_std"],
            )
            points[key] = max(points.get(key, 0), spec["seed"] + 1)
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
        f"ablate-threshold-{profile}-{env_id}-s{n_seeds}",
        storage,
        [],
        out_dir,
        t2_rule_standing(env_id, store, profile),
    )
