"""Beyond the paper: DRL-EG against today's demonstration-guided RL (IBRL, RLPD, JSRL).

Every method learns from the same demonstration files and seeds as DRL-EG. Scores are
normalised per task by the demonstrations and a uniform random policy,
(R - R_random) / (R_demo - R_random), so tasks of different reward scales aggregate; the
statistics are those of Agarwal et al. (2021): the interquartile mean over runs and tasks
with stratified-bootstrap CIs, the probability that DRL-EG beats each method, performance
profiles and sample-efficiency curves (IQM normalised score against the share of each
task's budget). The verdict table reads like the claims ledger: DRL-EG better, worse or
inconclusive per method and task, from the bootstrap CI of the difference of mean final
normalised scores.
"""

from __future__ import annotations

import base64
import functools
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from replicate.claims.checks import EQUIVALENT, FAILS, HOLDS, PAIRED, Check, decide
from replicate.claims.judge import SMALLEST_EFFECT
from replicate.claims.verdicts import what_would_decide
from replicate.errors import HarnessError
from replicate.figures.training import train_and_report
from replicate.grids.drl_eg_settings import env_settings, guidance_settings
from replicate.grids.experiments import GridOptions
from replicate.grids.profiles import BUDGETS, GridOutcome, Profile, get_profile, report_dir
from replicate.grids.train import algorithm_overrides, stored_outcome
from replicate.reports.pages import drl_eg_improvement
from replicate.stats import (
    CONFIDENCE,
    interquartile_mean,
    score_profile,
    seed_matched_difference,
    stratified_bootstrap_ci,
    substream,
)
from replicate.store.runner import Run
from replicate.store.spec import RunSpec

RLFD_ALGORITHMS = ("sac", "drl-eg", "ibrl", "rlpd", "jsrl", "ddpgfd")
MOUNTAINCAR = "MountainCarContinuous-v0"
CARTPOLE_SPARSE = "dm_control/cartpole-swingup_sparse-v0"
BALL_IN_CUP = "dm_control/ball_in_cup-catch-v0"
# Reward only in goal states: RLPD's official runs on such tasks (Antmaze, Adroit binary) set
# backup_entropy=False; its locomotion runs keep the default (on), as MuJoCo and MountainCar
# do here.
SPARSE_TASKS = (CARTPOLE_SPARSE, BALL_IN_CUP)
RLFD_BUDGETS = BUDGETS["rlfd"]  # (env steps, evaluation interval) per profile and task
RLFD_SEEDS = 5
RANDOM_EPISODES = 10
REPORT_SEED = 20_261_126
CURVE_FRACTIONS = np.linspace(0.0, 1.0, 11)  # sample-efficiency curve: shares of the budget


def rlfd_grid(
    profile: Profile, seeds: int | None = None, algorithms: tuple[str, ...] | None = None
) -> tuple[list[RunSpec], list[tuple[str, str, str]]]:
    """Every method x task x seed of the profile, and the (task, method, reason) cells left
    out: a method not registered, or a task without demonstrations."""
    from baselines.registry import UnknownAlgorithmError, get_algorithm
    from replicate.demos import default_demo_path

    n_seeds = RLFD_SEEDS if seeds is None else seeds
    if n_seeds <= 0:
        raise HarnessError(f"number of seeds must be positive, got {n_seeds}", "pass --seeds 5")
    specs, skipped = [], []
    for env_id, (steps, interval) in RLFD_BUDGETS[profile.name].items():
        for algo in algorithms or RLFD_ALGORITHMS:
            try:
                algorithm = get_algorithm(algo)
            except UnknownAlgorithmError:
                skipped.append((env_id, algo, "not registered in this checkout"))
                continue
            if algorithm.needs_demos and not default_demo_path(env_id).is_file():
                skipped.append((env_id, algo, "no committed demonstrations for this env yet"))
                continue
            hyper = algorithm_overrides(algo, profile.overrides)
            hyper.update(env_settings(algo, env_id, profile.name))
            if algo == "rlpd" and env_id in SPARSE_TASKS:
                hyper["backup_entropy"] = False
            specs += [
                RunSpec(algo, env_id, seed, steps, interval, profile.eval_episodes, hyper)
                for seed in range(n_seeds)
            ]
    return specs, skipped


@functools.cache
def random_return(env_id: str, episodes: int = RANDOM_EPISODES, seed: int = 0) -> float:
    """Mean return of uniformly random actions over ``episodes`` episodes (seeded)."""
    from envs import make_env

    env = make_env(env_id, seed=seed)
    env.action_space.seed(seed)
    totals = []
    for _ in range(episodes):
        env.reset()
        total, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            total += float(reward)
            done = terminated or truncated
        totals.append(total)
    env.close()
    return float(np.mean(totals))


def normalised(returns: np.ndarray, random: float, demo: float) -> np.ndarray:
    """(R - R_random) / (R_demo - R_random): 0 is random play, 1 the demonstrations."""
    span = demo - random
    if span <= 0:
        raise HarnessError(
            f"the demonstrations' return {demo:.3g} is not above random play's {random:.3g}",
            "retrain the expert and regenerate demonstrations",
        )
    return (np.asarray(returns, float) - random) / span


def _at_fractions(run: Run, budget: int) -> np.ndarray:
    """The run's evaluation return at each share of the budget in CURVE_FRACTIONS."""
    steps = run.curve["step"].to_numpy(float)
    return np.interp(CURVE_FRACTIONS * budget, steps, run.curve["return_mean"].to_numpy(float))


def compare(runs: list[Run], budgets: dict[str, tuple[int, int]], seed: int) -> dict[str, Any]:
    """The statistics of the report from complete runs (pure given the runs and seed): each
    verdict bootstraps on its own stream, so cells added later leave it as it was."""
    by_cell: dict[tuple[str, str], list[Run]] = {}
    for run in runs:
        by_cell.setdefault((run.spec["env_id"], run.spec["algo"]), []).append(run)
    tasks = [t for t in budgets if any(e == t for e, _ in by_cell)]
    algos = [a for a in RLFD_ALGORITHMS if any(x == a for _, x in by_cell)]
    reference = {}
    for task in tasks:
        demo = next(
            (
                r.provenance["demos"]["expert_return_mean"]
                for (e, _), members in by_cell.items()
                if e == task
                for r in members
                if r.provenance.get("demos")
            ),
            None,
        )
        if demo is None:  # only methods without demonstrations (SAC) have runs here yet
            from replicate.demos import default_demo_path, load_demos

            demo = load_demos(default_demo_path(task), task).mean_return
        reference[task] = {"random": random_return(task), "demo": float(demo)}

    def scores(task: str, algo: str) -> np.ndarray:
        ref = reference[task]
        finals = [
            r.final_return for r in sorted(by_cell[(task, algo)], key=lambda r: r.spec["seed"])
        ]
        return normalised(np.array(finals), ref["random"], ref["demo"])

    def by_seed(task: str, algo: str) -> dict[int, float]:
        seeds = sorted(r.spec["seed"] for r in by_cell[(task, algo)])
        return dict(zip(seeds, scores(task, algo).tolist()))

    cells = [
        {
            "env_id": t,
            "algo": a,
            "n": len(by_cell[(t, a)]),
            "final_normalised": float(np.mean(scores(t, a))),
            "runs": sorted(r.path.name for r in by_cell[(t, a)]),
        }
        for t in tasks
        for a in algos
        if (t, a) in by_cell
    ]

    # One family of checks, Holm-adjusted: "DRL-EG minus X above 0" per task and method,
    # paired with SAC only (shared initial weights); within +-SMALLEST_EFFECT: equivalent.
    checks = []
    for task in tasks:
        if (task, "drl-eg") not in by_cell:
            continue
        for algo in algos:
            if algo == "drl-eg" or (task, algo) not in by_cell:
                continue
            diff = seed_matched_difference(
                by_seed(task, "drl-eg"),
                by_seed(task, algo),
                f"{task}: DRL-EG minus {algo}, final normalised score",
                pair=algo in PAIRED,  # SAC shares DRL-EG's initial weights seed by seed
            )
            checks.append(
                Check(
                    f"{task}: DRL-EG minus {algo}", diff, above=0.0, smallest_effect=SMALLEST_EFFECT
                )
            )
    decide(checks)
    words = {HOLDS: "DRL-EG better", FAILS: "DRL-EG worse", EQUIVALENT: "equivalent"}
    verdicts = [
        {
            "env_id": c.estimate.quantity.split(":")[0],
            "other": c.what.rsplit(" minus ", 1)[1],
            "effect": c.estimate.value,
            "low": c.estimate.low,
            "high": c.estimate.high,
            "method": c.estimate.label,
            "quantity": c.estimate.as_dict(),
            "p_adjusted": c.adjusted,
            "p_unadjusted": c.unadjusted,
            "verdict": words.get(c.state, c.state),
            "decide": (what_would_decide(c, len(checks)) or (None,))[0],
        }
        for c in checks
    ]

    # Aggregates over the tasks where every method has runs, on as many seeds as all have.
    full = [t for t in tasks if all((t, a) in by_cell for a in algos)]
    aggregate = None
    if full and algos:
        n = min(len(by_cell[(t, a)]) for t in full for a in algos)
        if n >= 2:
            rng = substream(seed, "aggregate")
            matrix = {a: np.stack([scores(t, a)[:n] for t in full], axis=1) for a in algos}
            taus = np.linspace(0.0, 1.5, 61)
            iqm, profiles, efficiency = {}, {}, {}
            for algo in algos:
                est = stratified_bootstrap_ci(interquartile_mean, (matrix[algo],), rng)
                iqm[algo] = [float(est.value), float(est.low), float(est.high)]
                prof = stratified_bootstrap_ci(
                    lambda s: score_profile(s, taus), (matrix[algo],), rng
                )
                profiles[algo] = (prof.value, prof.low, prof.high)
                curves = np.stack(
                    [
                        np.stack(
                            [
                                normalised(
                                    _at_fractions(r, budgets[t][0]),
                                    reference[t]["random"],
                                    reference[t]["demo"],
                                )
                                for r in sorted(by_cell[(t, algo)], key=lambda r: r.spec["seed"])[
                                    :n
                                ]
                            ]
                        )
                        for t in full
                    ],
                    axis=1,
                )  # (runs, tasks, fractions)
                points = [
                    stratified_bootstrap_ci(interquartile_mean, (curves[:, :, k],), rng)
                    for k in range(len(CURVE_FRACTIONS))
                ]
                efficiency[algo] = tuple(
                    np.array([float(getattr(p, part)) for p in points])
                    for part in ("value", "low", "high")
                )
            improvement = drl_eg_improvement(matrix, algos, rng)
            aggregate = {
                "tasks": full,
                "runs_per_task": n,
                "iqm": iqm,
                "improvement": improvement,
                "taus": taus,
                "profiles": profiles,
                "efficiency": efficiency,
            }
    return {
        "tasks": tasks,
        "algos": algos,
        "reference": reference,
        "cells": cells,
        "verdicts": verdicts,
        "aggregate": aggregate,
    }


def _figure(aggregate: dict[str, Any]) -> bytes:
    """IQM with CIs, performance profiles, and the IQM against the share of the budget, two
    panels a row, with one legend in the free cell."""
    from replicate.figures.plots import (
        algo_color,
        algo_handle,
        algo_order,
        draw_iqm,
        draw_profiles,
        panel_grid,
        png_bytes,
        set_theme,
        shared_legend,
    )

    set_theme()
    algos = algo_order(list(aggregate["iqm"]))
    fig, (left, middle, right), slot = panel_grid(3, 2, 3.8)
    draw_iqm(left, {a: tuple(aggregate["iqm"][a]) for a in algos}, "IQM of final normalised score")
    draw_profiles(
        middle,
        aggregate["taus"],
        {a: aggregate["profiles"][a] for a in algos if a in aggregate["profiles"]},
        "normalised score tau",
    )
    for algo in algos:
        if algo not in aggregate["efficiency"]:
            continue
        value, low, high = aggregate["efficiency"][algo]
        right.plot(CURVE_FRACTIONS, value, color=algo_color(algo), linewidth=2)
        right.fill_between(
            CURVE_FRACTIONS, low, high, color=algo_color(algo), alpha=0.15, linewidth=0
        )
    right.set_xlabel("share of each task's env-step budget")
    right.set_ylabel("IQM normalised score")
    shared_legend(fig, [algo_handle(a) for a in algos], algos, slot)
    return png_bytes(fig)


def write_rlfd_report(
    outcome: GridOutcome,
    profile: Profile,
    out_dir: Path,
    guidance: list[dict[str, Any]] | None = None,
) -> Path:
    """Write the comparison's ``index.html`` and ``summary.json`` into ``out_dir``;
    ``guidance`` (``drl_eg_settings.guidance_settings``) is printed beside the verdicts."""
    from replicate.reports.pages import mujoco_threats, write_report
    from replicate.store import provenance

    budgets = RLFD_BUDGETS[profile.name]
    result = compare(outcome.runs, budgets, REPORT_SEED)
    aggregate = result["aggregate"]
    context = {
        "title": f"DRL-EG against IBRL, RLPD and JSRL, profile '{profile.name}'",
        "profile": profile,
        "budgets": budgets,
        "result": result,
        "confidence": CONFIDENCE,
        "smallest_effect": SMALLEST_EFFECT,
        "figure_png_b64": base64.b64encode(_figure(aggregate)).decode() if aggregate else None,
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "failed": outcome.failed,
        "skipped": outcome.skipped,
        "random_episodes": RANDOM_EPISODES,
        "guidance": guidance or [],
        "other_profiles": _other_profiles(profile.name, out_dir),
        "threats": mujoco_threats(outcome.runs),
        "revisions": sorted({r.provenance["git_revision"] for r in outcome.runs})
        or [provenance.git_revision()],
    }
    summary = {
        "profile": profile.name,
        "generated": context["generated"],
        "budgets": {t: list(b) for t, b in budgets.items()},
        "reference": result["reference"],
        "run_ids": [run for cell in result["cells"] for run in cell["runs"]],
        "cells": result["cells"],
        "verdicts": result["verdicts"],
        "guidance": guidance or [],
        "aggregate": None
        if aggregate is None
        else {k: aggregate[k] for k in ("tasks", "runs_per_task", "iqm", "improvement")},
        "failed": [{"run_id": i, "reason": why} for i, why in outcome.failed],
        "skipped": [{"env_id": e, "algo": a, "reason": why} for e, a, why in outcome.skipped],
        "git_revisions": context["revisions"],
        "threats": context["threats"],
    }
    return write_report(out_dir, "rlfd.html", context, summary)


def _other_profiles(profile: str, out_dir: Path) -> list[dict[str, Any]]:
    """The comparison at every other meaningful profile: its tasks, its report's path in
    the repository, and a link relative to ``out_dir`` when this report is written where
    the profile's reports go by default (``reports/`` or ``reports/<profile>/``, a rebuild's
    folder beside it too), else None: elsewhere the other reports are not beside it."""
    here = report_dir(profile, "rlfd").parent.parts
    default_layout = Path(out_dir).resolve().parent.parts[-len(here) :] == here
    others = []
    for name in RLFD_BUDGETS:
        if name in ("smoke", profile):
            continue
        there = report_dir(name, "rlfd") / "index.html"
        href = Path(os.path.relpath(there, report_dir(profile, "rlfd"))).as_posix()
        built = default_layout and (Path(out_dir) / href).resolve().is_file()
        others.append(
            {
                "name": name,
                "tasks": list(RLFD_BUDGETS[name]),
                "path": there.as_posix(),
                "href": href if built else None,
            }
        )
    return others


def run_rlfd(
    profile: str = "quick",
    seeds: int | None = None,
    store: Path = Path("runs"),
    out_dir: Path | None = None,
    algos: list[str] | None = None,
    envs: list[str] | None = None,
    options: GridOptions = GridOptions(),
) -> Path | None:
    """Train what the comparison lacks (only the cells of ``algos`` x ``envs`` when given),
    then write its report from every run of its grid in the store; return the report's
    path. A dry run (``options.dry_run``) prints what would train, trains and writes
    nothing, and returns None."""
    chosen = get_profile(profile)
    specs, skipped = rlfd_grid(chosen, seeds)
    return train_and_report(
        specs,
        skipped,
        profile,
        rlfd_command(profile),
        store,
        Path(out_dir or report_dir(profile, "rlfd")),
        lambda outcome, out: write_rlfd_report(
            outcome, chosen, out, guidance_settings(profile, outcome.runs, specs)
        ),
        algos,
        envs,
        options,
    )


def rlfd_command(profile: str) -> str:
    """The command that trains the comparison's grid at ``profile``."""
    return f"nox -s compare-rlfd -- --profile {profile}"


def rebuild_rlfd(
    profile: str, store: Path, out_dir: Path | None = None, seeds: int | None = None
) -> Path | None:
    """The report from the store alone; None (nothing written) when it holds none of the
    grid's runs, so that a committed report stays."""
    chosen = get_profile(profile)
    specs, skipped = rlfd_grid(chosen, seeds)
    outcome = stored_outcome(specs, skipped, profile, store, rlfd_command(profile))
    if outcome is None:
        return None
    return write_rlfd_report(
        outcome,
        chosen,
        Path(out_dir or report_dir(profile, "rlfd")),
        guidance_settings(profile, outcome.runs, specs),
    )
