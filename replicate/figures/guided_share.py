"""How often DRL-EG's guider acts: for every DRL-EG run of a profile's Fig. 3 budgets in the
store, the share of training steps on which the guider chose the action, per evaluation
interval over training. A figure added as a plug-in (its ``FIGURE``, named in the figure
registry): it trains nothing and reads only the run store."""

from __future__ import annotations

import base64
from collections import defaultdict
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from replicate.claims.confirm_judge import SEED_BLOCK
from replicate.figures.figure import FigureReport
from replicate.grids.drl_eg_settings import GUIDED_ALGORITHMS, T2_ALGORITHMS, drl_eg_env_defaults
from replicate.grids.profiles import BUDGETS
from replicate.reports.words import budget_words, seed_words
from replicate.store.query import Cell, select
from replicate.store.runs import Run, completed_runs

NAME = "guided-share"


def guided_runs(profile: str, store: Path) -> list[Run]:
    """The store's DRL-EG runs of ``profile``'s Fig. 3 cells: at its budget for their env and
    with the T2 in force there (the threshold ablation's other T2 values are cells of their
    own), at the grid's seeds (a confirmatory plan's fresh seeds, ``confirm_judge.SEED_BLOCK``
    on, are judged on their own)."""

    every = completed_runs(store)
    found = []
    for env_id, (steps, interval) in BUDGETS["fig3"][profile].items():
        for algo in GUIDED_ALGORITHMS:
            cell = Cell(algo, env_id, steps, interval, seeds=(0, SEED_BLOCK))
            runs = select(every, cell)
            if runs and algo in T2_ALGORITHMS:  # T2 in force: read only where there are runs
                t2 = drl_eg_env_defaults(env_id, profile, algo)["guide_threshold"]
                runs = select(runs, replace(cell, settings={"guide_threshold": t2}))
            found += runs
    return sorted(found, key=lambda run: run.path.name)


def guided_share_png(runs: list[Run], title: str) -> bytes:
    """One panel per env: each run's guided share per evaluation interval, thin lines in
    its algorithm's colour."""
    from replicate.figures.plots import algo_color, algo_handle, env_panels, finished_png

    fig, panels, slot = env_panels(runs, 3.2, "share of steps guided")
    for ax, env_runs in panels:
        for run in env_runs:
            curve = run.curve.iloc[1:]  # the step-0 point has no interval before it
            ax.plot(
                curve["step"],
                curve["guided_fraction"],
                color=algo_color(run.spec["algo"]),
                linewidth=1.0,
                alpha=0.8,
            )
        ax.set_ylim(-0.02, 1.02)
    algos = sorted({r.spec["algo"] for r in runs})
    return finished_png(fig, [algo_handle(a) for a in algos], algos, slot, title)


def write_guided_share_report(runs: list[Run], profile: str, out_dir: Path) -> Path:
    from replicate.reports.pages import write_report

    cells: dict[tuple[str, str], list[Run]] = defaultdict(list)
    for run in runs:
        cells[(run.spec["env_id"], run.spec["algo"])].append(run)
    rows = [
        {
            "env_id": env_id,
            "algo": algo,
            "seeds": sorted(r.spec["seed"] for r in members),
            "steps": int(members[0].spec["total_steps"]),
            "shares": [r.guided_share for r in members],
            "mean_share": float(np.mean([r.guided_share for r in members])),
            "runs": sorted(r.path.name for r in members),
        }
        for (env_id, algo), members in sorted(cells.items())
    ]
    title = f"How often DRL-EG's guider acts, profile '{profile}'"
    context = {
        "title": title,
        "profile": profile,
        "rows": rows,
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "figure_png_b64": base64.b64encode(guided_share_png(runs, title)).decode(),
    }
    summary = {
        "profile": profile,
        "generated": context["generated"],
        "run_ids": [run for row in rows for run in row["runs"]],
        "rows": rows,
    }
    return write_report(out_dir, "guided_share.html", context, summary)


def rebuild(profile: str, store: Path, out_dir: Path, seeds: int | None) -> Path | None:
    """The report from the store's DRL-EG runs of ``profile``; None without any."""
    runs = guided_runs(profile, Path(store))
    return write_guided_share_report(runs, profile, out_dir) if runs else None


def describe(summary: dict[str, Any]) -> dict[str, str]:
    return {
        "covers": "How often DRL-EG's guider acts over training, every DRL-EG run",
        "budget": budget_words([row["steps"] for row in summary["rows"]]),
        "seeds": seed_words([len(row["seeds"]) for row in summary["rows"]]),
    }


FIGURE = FigureReport(NAME, rebuild, describe)
