"""Fig. 3 of the paper: every algorithm on every env of a profile, the learning curves, the
claims ledger (claims 1-4; claim 5 from Fig. 4's runs) and what surrounds it (aggregates,
sample efficiency, our SAC against published SAC). Its grid, budgets (in
``profiles.BUDGETS["fig3"]``), training command and report writer, in one place."""

from __future__ import annotations

import base64
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from replicate.claims.checks import Group
from replicate.claims.groups import claim_groups, curve_matrix, group_runs
from replicate.claims.published import FAMILY_TITLES, published_points
from replicate.errors import HarnessError
from replicate.figures.forest import forest_images
from replicate.figures.plots import CurveBand, aggregate_png, learning_curves_png
from replicate.figures.training import train_and_report
from replicate.grids.drl_eg_settings import env_settings, guidance_settings
from replicate.grids.experiments import GridOptions
from replicate.grids.profiles import (
    PAPER_BUDGETS,
    PAPER_SEEDS_FIG3,
    GridOutcome,
    Profile,
    get_profile,
)
from replicate.grids.train import algorithm_overrides, stored_outcome
from replicate.reports.pages import (
    REPORT_SEED,
    demo_returns,
    drl_eg_improvement,
    ledger,
    published_rows,
    sac_standing,
    threats_to_validity,
    write_report,
)
from replicate.stats import (
    CONFIDENCE,
    interquartile_mean,
    score_profile,
    steps_to_reach,
    stratified_bootstrap_ci,
    substream,
    t_mean,
    t_mean_columns,
)
from replicate.store import provenance
from replicate.store.measures import final_returns
from replicate.store.runs import Run
from replicate.store.spec import RunSpec

FIG3_ALGORITHMS = ("sac", "ppo", "ppo-bc", "ddpgfd", "drl-eg", "drl-eg-gmm")


def figure3_grid(
    profile: Profile, seeds: int | None = None
) -> tuple[list[RunSpec], list[tuple[str, str, str]]]:
    """The Fig. 3 grid: every algorithm x env x seed of the profile, and the (env, algo,
    reason) cells left out because their demonstrations do not exist yet."""
    from baselines.registry import get_algorithm
    from replicate.demos import default_demo_path

    n_seeds = profile.seeds if seeds is None else seeds
    if n_seeds <= 0:
        raise HarnessError(f"number of seeds must be positive, got {n_seeds}", "pass --seeds 3")
    specs, skipped = [], []
    for env_id in profile.steps:
        for algo in FIG3_ALGORITHMS:
            if get_algorithm(algo).needs_demos and not default_demo_path(env_id).is_file():
                skipped.append(
                    (
                        env_id,
                        algo,
                        "no committed demonstrations for this env yet "
                        "(`nox -s experts`, then `nox -s demos`)",
                    )
                )
                continue
            hyper = algorithm_overrides(algo, profile.overrides)
            hyper.update(env_settings(algo, env_id, profile.name))
            for seed in range(n_seeds):
                specs.append(
                    RunSpec(
                        algo=algo,
                        env_id=env_id,
                        seed=seed,
                        total_steps=profile.steps[env_id],
                        eval_interval=profile.eval_interval[env_id],
                        eval_episodes=profile.eval_episodes,
                        hyperparameters=hyper,
                    )
                )
    return specs, skipped


def run_figure3(
    profile: str = "quick",
    seeds: int | None = None,
    store: Path = Path("runs"),
    out_dir: Path = Path("reports/fig3"),
    algos: list[str] | None = None,
    envs: list[str] | None = None,
    options: GridOptions = GridOptions(),
) -> Path | None:
    """Train the Fig. 3 grid (what is missing; only the cells of ``algos`` x ``envs`` when
    given) and write its HTML report from every run of the grid in the store; return its
    path. A dry run (``options.dry_run``) prints what would train, trains and writes
    nothing, and returns None."""
    chosen = get_profile(profile)
    specs, skipped = figure3_grid(chosen, seeds)
    return train_and_report(
        specs,
        skipped,
        profile,
        figure3_command(profile),
        store,
        out_dir,
        lambda outcome, out: write_figure3_report(
            outcome,
            chosen,
            out,
            guidance_settings(profile, outcome.runs, specs),
            _figure4_runs(profile, Path(store)),
            _random_start_rows(profile, Path(store)),
        ),
        algos,
        envs,
        options,
    )


def figure3_command(profile: str) -> str:
    """The command that trains the Fig. 3 grid at ``profile`` (named beside missing cells)."""
    return f"nox -s replicate-fig3 -- --profile {profile}"


def rebuild_figure3(
    profile: str = "quick",
    seeds: int | None = None,
    store: Path = Path("runs"),
    out_dir: Path = Path("reports/fig3"),
) -> Path | None:
    """Write the Fig. 3 report from the runs already in the store; train nothing. Cells of
    the grid whose runs are missing are listed in the report. With none of the grid's runs
    in the store, nothing is written (a committed report is not replaced by an empty one)
    and None is returned."""
    chosen = get_profile(profile)
    specs, skipped = figure3_grid(chosen, seeds)
    outcome = stored_outcome(specs, skipped, profile, store, figure3_command(profile))
    if outcome is None:
        return None
    return write_figure3_report(
        outcome,
        chosen,
        out_dir,
        guidance_settings(profile, outcome.runs, specs),
        _figure4_runs(profile, Path(store)),
        _random_start_rows(profile, Path(store)),
    )


def _random_start_rows(profile: str, store: Path) -> list[dict[str, Any]]:
    """The random-start study's rows from the store (the threats box reports its effect)."""
    from replicate.figures.random_start import stored_rows

    return stored_rows(profile, store)


def _figure4_runs(profile: str, store: Path) -> list[Run]:
    """Fig. 4's runs of ``profile`` in the store (claim 5 is judged on them)."""
    from replicate.figures.fig4 import figure4_runs  # Fig. 4 builds on this module

    return figure4_runs(profile, store)


@dataclass
class FinalReturns:
    env_id: str
    algo: str
    seeds: list[int]
    finals: np.ndarray
    mean: float
    low: float
    high: float


def summarise(runs: list[Run]) -> tuple[list[CurveBand], list[FinalReturns]]:
    """Each (env, algorithm)'s curve band and final returns, with t-intervals over seeds."""
    bands, finals = [], []
    for (env_id, algo), members in sorted(group_runs(runs).items()):
        steps, matrix = curve_matrix(members)
        band = t_mean_columns(matrix)
        bands.append(
            CurveBand(
                algo,
                env_id,
                steps,
                band.value,
                band.low,
                band.high,
                len(members),
                matrix,
                [r.spec["seed"] for r in members],
            )
        )
        last = final_returns(steps, matrix)  # the declared late-training mean
        est = t_mean(last)
        finals.append(
            FinalReturns(
                env_id, algo, [r.spec["seed"] for r in members], last, est.value, est.low, est.high
            )
        )
    return bands, finals


def aggregate_metrics(
    groups: dict[tuple[str, str], Group], demo_returns: dict[str, float], rng: np.random.Generator
) -> dict[str, Any] | None:
    """IQM, performance profiles and probability of improvement over the envs that have
    demonstrations, on final returns divided by the demonstrations' return (Agarwal et
    al. 2021). An algorithm takes the same number of runs on every env (its smallest cell's,
    its first seeds), which the stratified bootstrap needs; algorithms may differ."""
    algos = sorted({a for _, a in groups})
    tasks = [
        e
        for e in sorted({e for e, _ in groups})
        if e in demo_returns and all((e, a) in groups for a in algos)
    ]
    if not tasks or not algos:
        return None
    runs = {a: min(len(groups[(e, a)].finals) for e in tasks) for a in algos}
    if min(runs.values()) < 2:
        return None
    scores = {
        a: np.stack(
            [groups[(e, a)].finals[: runs[a]] / abs(demo_returns[e]) for e in tasks], axis=1
        )
        for a in algos
    }
    taus = np.linspace(0.0, 1.2, 49)
    iqm, profiles = {}, {}
    for algo in algos:
        est = stratified_bootstrap_ci(interquartile_mean, (scores[algo],), rng)
        iqm[algo] = (float(est.value), float(est.low), float(est.high))
        prof = stratified_bootstrap_ci(lambda s: score_profile(s, taus), (scores[algo],), rng)
        profiles[algo] = (prof.value, prof.low, prof.high)
    improvement = drl_eg_improvement(scores, algos, rng)
    png = aggregate_png(iqm, taus, profiles)
    return {
        "tasks": tasks,
        "runs_per_task": runs,
        "iqm": iqm,
        "improvement": improvement,
        "png_b64": base64.b64encode(png).decode(),
    }


REACH_FRACTION = 0.5  # sample efficiency: env steps to half of the demonstrations' return


def efficiency_rows(
    groups: dict[tuple[str, str], Group], demo_returns: dict[str, float]
) -> list[dict[str, Any]]:
    """Per (env, algorithm) with demonstrations: area under the curve with a t-interval
    over seeds, and how soon seeds reach ``REACH_FRACTION`` of the demonstrations' return:
    how many do, the fastest and slowest of them, and the step by which half of all seeds
    have (a seed that never reaches it counts as beyond the budget, so no mean or interval
    is taken over the seeds that happen to reach it)."""
    rows = []
    for (env_id, algo), group in sorted(groups.items()):
        if env_id not in demo_returns:
            continue
        level = REACH_FRACTION * demo_returns[env_id]
        area = t_mean(group.areas)
        reached = np.sort(steps_to_reach(group.steps, group.curves, level))
        reached = reached[np.isfinite(reached)]
        half = -(-len(group.seeds) // 2)  # half of the seeds, rounded up
        rows.append(
            {
                "env_id": env_id,
                "algo": algo,
                "n": len(group.seeds),
                "area": {"mean": area.value, "low": area.low, "high": area.high, "n": area.n},
                "reach": {
                    "n": int(len(reached)),
                    "half_of_seeds": float(reached[half - 1]) if len(reached) >= half else None,
                    "fastest": float(reached[0]) if len(reached) else None,
                    "slowest": float(reached[-1]) if len(reached) else None,
                },
                "level": level,
            }
        )
    return rows


def seed_counts(runs: list[Run]) -> str:
    """How many seeds the report's cells hold, from the runs: '5 seeds in 6 cells, 3 in
    14' (per cell in the report's Budgets)."""
    counts = sorted((len(members) for members in group_runs(runs).values()), reverse=True)
    if not counts:
        return "no runs yet"
    tally = {n: counts.count(n) for n in dict.fromkeys(counts)}
    parts = [f"{n} in {k} cell{'s' if k != 1 else ''}" for n, k in tally.items()]
    return "seeds per cell: " + ", ".join(parts)


def write_figure3_report(
    outcome: GridOutcome,
    profile: Profile,
    out_dir: Path,
    guidance: list[dict[str, Any]] | None = None,
    fig4_runs: list[Run] | None = None,
    random_start_rows: list[dict[str, Any]] | None = None,
) -> Path:
    """Write ``out_dir/index.html`` (self-contained) and ``out_dir/summary.json``;
    ``guidance`` (``drl_eg_settings.guidance_settings``) is printed beside the claims;
    ``fig4_runs``: the profile's Fig. 4 runs in the store, which judge claim 5;
    ``random_start_rows``: the random-start study's rows, for the threats box."""
    from replicate.figures.random_start import start_threat  # a figure module of its own

    runs = outcome.runs
    bands, finals = summarise(runs) if runs else ([], [])
    demo_lines = demo_returns(runs)
    demos = {}
    for run in runs:
        info = run.provenance.get("demos")
        if info:
            demos[info["sha256"]] = dict(info, env_id=run.spec["env_id"])
    groups = claim_groups(runs)
    claims = ledger(runs, fig4_runs or [], profile)
    aggregate = aggregate_metrics(groups, demo_lines, substream(REPORT_SEED, "aggregate"))
    efficiency = efficiency_rows(groups, demo_lines)
    published = published_rows(groups, profile.steps)
    title = f"Fig. 3 replication, profile '{profile.name}'"
    points = {
        env_id: [
            (p.steps, p.mean, p.std, p.family)
            for p in published_points(env_id, steps)
            if p.source in ("tianshou", "spinningup", "coach")
        ]
        for env_id, steps in profile.steps.items()
        if env_id in {b.env_id for b in bands}
    }
    figure = (
        base64.b64encode(
            learning_curves_png(bands, demo_lines, title, points, list(profile.steps))
        ).decode()
        if bands
        else None
    )
    revisions = sorted({r.provenance["git_revision"] for r in runs})
    first = runs[0].provenance if runs else {}
    budgets = [
        {
            "env_id": env_id,
            "steps": profile.steps[env_id],
            "eval_interval": profile.eval_interval[env_id],
            "eval_episodes": profile.eval_episodes,
            "seeds": {
                algo: sorted(r.spec["seed"] for r in members)
                for (env, algo), members in sorted(group_runs(runs).items())
                if env == env_id
            },
            "paper": PAPER_BUDGETS.get(env_id, "-"),
        }
        for env_id in profile.steps
    ]
    context = {
        "title": title,
        "profile": profile,
        "paper_seeds": PAPER_SEEDS_FIG3,
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "figure_png_b64": figure,
        "finals": finals,
        "claims": claims,
        "forests": forest_images(claims),
        "declaration": claims[0]["declaration"] if claims else None,
        "aggregate": aggregate,
        "budgets": budgets,
        "runs": sorted(runs, key=lambda r: (r.spec["env_id"], r.spec["algo"], r.spec["seed"])),
        "failed": outcome.failed,
        "skipped": outcome.skipped,
        "demos": list(demos.values()),
        "versions": first.get("versions", provenance.package_versions()),
        "machine": first.get("machine", provenance.machine()),
        "revisions": revisions or [provenance.git_revision()],
        "train_wall_s": sum(r.provenance["wall_time_s"] for r in runs),
        "grid_wall_s": outcome.wall_time_s,
        "confidence": CONFIDENCE,
        "efficiency": efficiency,
        "published": published,
        "reach_fraction": REACH_FRACTION,
        "guidance": guidance or [],
        "seed_counts": seed_counts(runs),
        "threats": threats_to_validity(
            runs, published, sac_start=start_threat(profile.name, random_start_rows or [])
        ),
        "sac_standing": sac_standing(published),
        "family_titles": FAMILY_TITLES,
    }
    summary = {
        "profile": profile.name,
        "generated": context["generated"],
        "claims": claims,
        "final_returns": [
            {
                "env_id": f.env_id,
                "algo": f.algo,
                "seeds": f.seeds,
                "finals": f.finals.tolist(),
                "mean": f.mean,
                "ci95": [f.low, f.high],
            }
            for f in finals
        ],
        "run_ids": [r.path.name for r in context["runs"]],
        "runs": [
            {
                "run_id": r.path.name,
                "spec_hash": r.provenance["spec_hash"],
                "final_return": r.final_return,
            }
            for r in context["runs"]
        ],
        "failed": [{"run_id": i, "reason": why} for i, why in outcome.failed],
        "skipped": [{"env_id": e, "algo": a, "reason": why} for e, a, why in outcome.skipped],
        "aggregate": None
        if aggregate is None
        else {k: aggregate[k] for k in ("tasks", "runs_per_task", "iqm", "improvement")},
        "efficiency": efficiency,
        "published_sac": published,
        "guidance": guidance or [],
        "git_revisions": context["revisions"],
        "seed_counts": context["seed_counts"],
        "budgets": {b["env_id"]: b["steps"] for b in budgets},
        "threats": context["threats"],
    }
    return write_report(out_dir, "fig3.html", context, summary)
