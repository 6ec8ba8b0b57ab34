"""Fig. 4 of the paper: SAC and DRL-EG on Ant from the same seeds, hence the same initial
weights, one panel per seed, the paired differences and claim 5. Its grid, budgets (in
``profiles.BUDGETS["fig4"]``), training command and report writer, in one place."""

from __future__ import annotations

import base64
from collections import defaultdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from replicate.claims.groups import claim_groups
from replicate.claims.judge import PAPER_FIG4_SEEDS
from replicate.errors import HarnessError
from replicate.figures.training import write_saying_why
from replicate.grids.drl_eg_settings import (
    T2_WAIT_REASON,
    drl_eg_env_defaults,
    guidance_settings,
    waits_for_t2_rule,
)
from replicate.grids.experiments import GridOptions
from replicate.grids.profiles import BUDGETS, GridOutcome, Profile, get_profile, report_dir
from replicate.grids.train import (
    algorithm_overrides,
    stored_outcome,
    train_cells,
)
from replicate.reports.pages import (
    ledger,
    published_rows,
    threats_to_validity,
    write_report,
)
from replicate.stats import CONFIDENCE, paired_mean_difference
from replicate.store.query import stored_runs
from replicate.store.runs import Run
from replicate.store.spec import RunSpec

FIG4_ENV = "Ant-v5"
FIG4_SEEDS = PAPER_FIG4_SEEDS  # the paper's four fixed seeds; claim 5 counts them too
FIG4_BUDGETS: dict[str, tuple[int, int]] = {  # profiles.BUDGETS["fig4"]: Ant's
    name: table[FIG4_ENV] for name, table in BUDGETS["fig4"].items()
}


def figure4_grid(
    profile: Profile, env_id: str = FIG4_ENV, seeds: int | None = None
) -> list[RunSpec]:
    """Fig. 4: SAC and DRL-EG on the same seeds, hence the same initial weights."""
    from replicate.demos import default_demo_path

    n_seeds = FIG4_SEEDS if seeds is None else seeds
    if n_seeds <= 0:
        raise HarnessError(f"number of seeds must be positive, got {n_seeds}", "pass --seeds 4")
    if not default_demo_path(env_id).is_file():
        raise HarnessError(
            f"Fig. 4 needs demonstrations for {env_id}, and none are committed",
            f"train its expert (`nox -s experts -- --env {env_id}`), then `nox -s demos`",
        )
    steps, interval = FIG4_BUDGETS[profile.name]
    specs = []
    for algo in ("sac", "drl-eg"):
        hyper = algorithm_overrides(algo, profile.overrides)
        if algo == "drl-eg":
            hyper.update(drl_eg_env_defaults(env_id, profile.name))
        specs += [
            RunSpec(algo, env_id, seed, steps, interval, profile.eval_episodes, hyper)
            for seed in range(n_seeds)
        ]
    return specs


def figure4_runs(profile: str, store: Path) -> list[Run]:
    """The profile's Fig. 4 runs on Ant in the store (claim 5 is judged on them); none
    without Ant's demonstrations."""
    from replicate.demos import default_demo_path

    if not default_demo_path(FIG4_ENV).is_file():
        return []
    return stored_runs(figure4_report_grid(get_profile(profile), FIG4_ENV, None), store)


def figure4_command(profile: str, env_id: str) -> str:
    """The command that trains the Fig. 4 grid at ``profile`` (named beside missing seeds)."""
    env = "" if env_id == FIG4_ENV else f" --env {env_id}"
    return f"nox -s replicate-fig4 -- --profile {profile}{env}"


def figure4_report_grid(profile: Profile, env_id: str, seeds: int | None) -> list[RunSpec]:
    """The pairs a Fig. 4 report covers: the paper's four seeds at least, so a command that
    trains fewer (``--seeds 1``, one pair at a time) writes a report that lists the rest as
    missing rather than one that looks complete."""
    n_seeds = FIG4_SEEDS if seeds is None else seeds
    return figure4_grid(profile, env_id, max(n_seeds, FIG4_SEEDS) if n_seeds > 0 else n_seeds)


def rebuild_figure4(
    profile: str = "quick",
    env_id: str = FIG4_ENV,
    seeds: int | None = None,
    store: Path = Path("runs"),
    out_dir: Path | None = None,
) -> Path | None:
    """Write the Fig. 4 report from the runs already in the store; train nothing; the seeds
    it lacks are listed. Returns None, writing nothing, when the store holds no run of it (a
    committed report stays)."""
    chosen = get_profile(profile)
    specs = figure4_report_grid(chosen, env_id, seeds)
    outcome = stored_outcome(specs, [], profile, store, figure4_command(profile, env_id))
    if outcome is None:
        return None
    out_dir = Path(out_dir or report_dir(profile, "fig4"))
    return write_figure4_report(
        outcome, chosen, env_id, out_dir, guidance_settings(profile, outcome.runs, specs)
    )


def run_figure4(
    profile: str = "quick",
    env_id: str = FIG4_ENV,
    seeds: int | None = None,
    store: Path = Path("runs"),
    out_dir: Path | None = None,
    options: GridOptions = GridOptions(),
) -> Path | None:
    """Train what Fig. 4 lacks and write its report; one that names runs the store lacks is
    replaced only by one naming as many (``report.write_unless_fewer``). Returns the
    report's path (None: nothing written, as with a dry run, which prints what would
    train)."""
    chosen = get_profile(profile)
    if waits_for_t2_rule(profile, env_id, "drl-eg"):
        raise HarnessError(
            f"Fig. 4 on {env_id} at the {profile} budget {T2_WAIT_REASON}",
            "run the ablation first, then fix MUJOCO_T2_RULE in "
            "replicate/grids/drl_eg_settings.py (docs/decisions.md: T2 on MuJoCo)",
        )
    to_train = figure4_grid(chosen, env_id, seeds)
    specs = figure4_report_grid(chosen, env_id, seeds)
    outcome = train_cells(
        specs,
        to_train,
        Path(store),
        figure4_command(profile, env_id),
        options,
    )
    if options.dry_run:
        return None
    out_dir = Path(out_dir or report_dir(profile, "fig4"))
    return write_saying_why(
        out_dir,
        Path(store),
        lambda out: write_figure4_report(
            outcome, chosen, env_id, out, guidance_settings(profile, outcome.runs, specs)
        ),
    )


def write_figure4_report(
    outcome: GridOutcome,
    profile: Profile,
    env_id: str,
    out_dir: Path,
    guidance: list[dict[str, Any]] | None = None,
) -> Path:
    """Fig. 4: one panel per seed, SAC against DRL-EG from identical initial weights, the
    paired differences, and claim 5 when the env is the paper's (Ant)."""
    from replicate.claims.judge import ANT, PAPER_FIG4_SEEDS
    from replicate.figures.forest import forest_images
    from replicate.figures.plots import paired_curves_png

    by_seed: dict[int, dict[str, Run]] = defaultdict(dict)
    for run in outcome.runs:
        by_seed[run.spec["seed"]][run.spec["algo"]] = run
    pairs = {seed: runs for seed, runs in sorted(by_seed.items()) if len(runs) == 2}
    rows = []
    for seed, runs in pairs.items():
        sac, drl = runs["sac"], runs["drl-eg"]
        rows.append(
            {
                "seed": seed,
                "sac": sac.final_return,
                "drl": drl.final_return,
                "difference": drl.final_return - sac.final_return,
                "guided_share": drl.guided_share,
                # same seed, same initial weights: the step-0 evaluations must agree
                "same_start": sac.curve["returns"].iloc[0] == drl.curve["returns"].iloc[0],
                "runs": [sac.path.name, drl.path.name],
            }
        )
    claim = None
    if env_id == ANT and pairs:  # the same verdict as the Fig. 3 report's ledger
        claim = next(c for c in ledger([], outcome.runs, profile) if c["runs"] == "fig4")
    paired = claim.get("paired") if claim else None
    if paired is None and rows:  # another env, or a profile that does not judge claim 5
        paired = paired_mean_difference(
            np.array([r["drl"] for r in rows]),
            np.array([r["sac"] for r in rows]),
            f"{env_id}: DRL-EG minus SAC, final return",
        ).as_dict()
    panels = [
        (
            seed,
            {
                algo: (
                    run.curve["step"].to_numpy(),
                    run.curve["return_mean"].to_numpy(),
                    run.curve["train_return"].to_numpy(float),
                )
                for algo, run in runs.items()
            },
        )
        for seed, runs in pairs.items()
    ]
    title = f"Fig. 4 replication on {env_id}, profile '{profile.name}'"
    context = {
        "title": title,
        "profile": profile,
        "env_id": env_id,
        "rows": rows,
        "paired": paired,
        "claim": claim,
        "forests": forest_images([claim] if claim else []),
        "declaration": claim["declaration"] if claim else None,
        "confidence": CONFIDENCE,
        "failed": outcome.failed,
        "missing": outcome.skipped,
        "figure_png_b64": base64.b64encode(paired_curves_png(panels, title)).decode()
        if panels
        else None,
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "steps": int(outcome.runs[0].spec["total_steps"]) if outcome.runs else 0,
        "revisions": sorted({r.provenance["git_revision"] for r in outcome.runs}),
        "guidance": guidance or [],
        "threats": threats_to_validity(
            outcome.runs,
            published_rows(
                claim_groups(outcome.runs),
                {env_id: int(outcome.runs[0].spec["total_steps"])} if outcome.runs else {},
            ),
            paper_seeds=PAPER_FIG4_SEEDS,
        ),
    }
    summary = {
        "profile": profile.name,
        "env_id": env_id,
        "run_ids": [run for row in rows for run in row["runs"]],
        "claim": claim,
        "paired": paired,
        "generated": context["generated"],
        "steps": context["steps"],
        "threats": context["threats"],
        "rows": [dict(r, same_start=bool(r["same_start"])) for r in rows],
        "guidance": guidance or [],
        "missing": [{"env_id": e, "algo": a, "reason": why} for e, a, why in outcome.skipped],
        "failed": [{"run_id": i, "reason": why} for i, why in outcome.failed],
    }
    return write_report(out_dir, "fig4.html", context, summary)
