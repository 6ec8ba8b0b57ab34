"""Our V-SAC with the SAC authors' random start against the default start: the same seeds
(so the same initial weights), with and without uniform-random actions for the first steps
(``random_start_steps``: 10,000 on HalfCheetah and Ant in the SAC authors' code), at a
profile's Fig. 3 budget. The default start's runs are Fig. 3's own SAC runs (the same
addresses); the report gives each env's paired difference in final return and area under
the curve."""

from __future__ import annotations

import argparse
import base64
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from replicate.figures.figure import FigureReport
from replicate.grids.options import Command, HelpFormatter, add_grid_arguments, run_figure
from replicate.grids.profiles import BUDGETS, PROFILES, GridOutcome, report_dir
from replicate.reports.words import budget_words, seed_words
from replicate.stats import curve_area, paired_mean_difference
from replicate.store.runs import Run
from replicate.store.spec import RunSpec

if TYPE_CHECKING:
    from replicate.grids.experiments import GridOptions

NAME = "random-start"
SEEDS = 3
# The SAC authors' random start per env; MountainCar's stands in for the smoke profile.
START_STEPS = {"HalfCheetah-v5": 10_000, "Ant-v5": 10_000, "MountainCarContinuous-v0": 400}
STUDY_ENVS = ("HalfCheetah-v5", "Ant-v5")


def study_envs(profile: str) -> list[str]:
    envs = [e for e in STUDY_ENVS if e in BUDGETS["fig3"][profile]]
    return envs or (["MountainCarContinuous-v0"] if not PROFILES[profile].meaningful else [])


def random_start_grid(profile: str, seeds: int | None = None) -> list[RunSpec]:
    """SAC on the study's envs, each seed with the default start (Fig. 3's run) and the random
    start."""
    from replicate.grids.train import algorithm_overrides

    chosen = PROFILES[profile]
    specs = []
    for env_id in study_envs(profile):
        steps, interval = BUDGETS["fig3"][profile][env_id]
        for start in (0, START_STEPS[env_id]):
            hyper = dict(algorithm_overrides("sac", chosen.overrides), random_start_steps=start)
            specs += [
                RunSpec("sac", env_id, seed, steps, interval, chosen.eval_episodes, hyper)
                for seed in range(SEEDS if seeds is None else seeds)
            ]
    return specs


def command(profile: str) -> str:
    return f"nox -s sac-random-start -- --profile {profile}"


def _start(run: Run) -> int:
    return int(run.spec["hyperparameters"].get("random_start_steps", 0))


def _area(run: Run) -> float:
    return float(curve_area(run.curve["step"].to_numpy(float), run.curve["return_mean"])[0])


def comparison_rows(runs: list[Run]) -> list[dict[str, Any]]:
    """Per env: each start's runs by seed, and the paired differences (random minus default)
    over the seeds that have both."""
    rows = []
    for env_id in sorted({r.spec["env_id"] for r in runs}):
        here = [r for r in runs if r.spec["env_id"] == env_id]
        default = {r.spec["seed"]: r for r in here if _start(r) == 0}
        random = {r.spec["seed"]: r for r in here if _start(r) > 0}
        shared = sorted(set(default) & set(random))
        quantity = f"{env_id}: SAC with a random start minus the default start"

        def paired(values: Any, what: str) -> dict[str, Any]:
            return paired_mean_difference(
                np.array([values(random[s]) for s in shared]),
                np.array([values(default[s]) for s in shared]),
                f"{quantity}, {what}",
            ).as_dict()

        rows.append(
            {
                "env_id": env_id,
                "steps": int(here[0].spec["total_steps"]),
                "random_start_steps": sorted({_start(r) for r in random.values()}),
                "default": {s: default[s].final_return for s in sorted(default)},
                "random": {s: random[s].final_return for s in sorted(random)},
                "final": paired(lambda r: r.final_return, "final return") if shared else None,
                "area": paired(_area, "area under the curve") if shared else None,
                "runs": sorted(r.path.name for r in here),
                "random_start_runs": sorted(r.path.name for r in random.values()),
            }
        )
    return rows


def stored_study(profile: str, store: Path, seeds: int | None = None) -> GridOutcome | None:
    """The study's runs in ``store``; None while none of its random-start runs is there (the
    default start's runs alone are Fig. 3's)."""
    from replicate.grids.train import stored_outcome

    outcome = stored_outcome(
        random_start_grid(profile, seeds), [], profile, store, command(profile)
    )
    if outcome is None or not any(_start(r) for r in outcome.runs):
        return None
    return outcome


def stored_rows(profile: str, store: Path) -> list[dict[str, Any]]:
    """The study's rows (``comparison_rows``) from the runs in ``store``; empty while none of
    its random-start runs is there."""
    outcome = stored_study(profile, store)
    return comparison_rows(outcome.runs) if outcome else []


def start_threat(profile: str, rows: list[dict[str, Any]]) -> str | None:
    """The threats-to-validity line on how our SAC starts, with the study's measured effect
    on each env where it has pairs (None for a profile without the study's envs)."""
    envs = [e for e in study_envs(profile) if e in STUDY_ENVS]
    if not envs:
        return None
    line = (
        "How our SAC starts: from its initial policy, where the SAC authors' code first takes "
        "uniform-random actions (1,000 steps on Hopper and Walker2d, 10,000 on HalfCheetah "
        "and Ant)"
    )
    measured = {row["env_id"]: row for row in rows if row.get("final")}
    if not measured:
        return (
            f"{line}; its effect is not measured yet ({command(profile)} measures it on "
            f"{' and '.join(envs)})."
        )
    parts = []
    for env_id in envs:
        row = measured.get(env_id)
        if row is None:
            parts.append(f"{env_id} not measured yet")
            continue
        final, at = row["final"], f"at {row['steps']:,} steps"
        if final["n"] < 2:
            parts.append(f"{env_id} {at}: {final['value']:+.0f} from 1 pair (no interval)")
            continue
        shown = (
            "random start higher"
            if final["low"] > 0
            else "random start lower"
            if final["high"] < 0
            else "the interval includes 0"
        )
        parts.append(
            f"{env_id} {at}: {final['value']:+.0f} [{final['low']:.0f}, {final['high']:.0f}], "
            f"{final['method']}, {shown}"
        )
    starts = " and ".join(sorted({f"{START_STEPS[e]:,}" for e in envs}))
    return (
        f"{line}. Measured with {starts} random steps, the final return with the random start "
        f"minus with the default start, paired by seed (each env on its own): "
        f"{'; '.join(parts)}."
    )


def curves_png(runs: list[Run], title: str) -> bytes:
    from matplotlib.lines import Line2D

    from replicate.figures.plots import algo_color, env_panels, finished_png

    fig, panels, slot = env_panels(runs, 3.6, "return")
    colour = algo_color("sac")
    for ax, env_runs in panels:
        for run in env_runs:
            style = "--" if _start(run) else "-"
            ax.plot(run.curve["step"], run.curve["return_mean"], style, color=colour, lw=1.2)
    handles = [Line2D([], [], color=colour, ls="-"), Line2D([], [], color=colour, ls="--")]
    labels = ["default start (initial policy)", "random start"]
    return finished_png(fig, handles, labels, slot, title)


def write_random_start_report(outcome: GridOutcome, profile: str, out_dir: Path) -> Path:
    from replicate.reports.pages import write_report

    rows = comparison_rows(outcome.runs)
    title = f"SAC's random start against the default start, profile '{profile}'"
    context = {
        "title": title,
        "profile": profile,
        "rows": rows,
        "missing": outcome.skipped,
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "figure_png_b64": base64.b64encode(curves_png(outcome.runs, title)).decode(),
    }
    summary = {
        "profile": profile,
        "generated": context["generated"],
        "run_ids": [run for row in rows for run in row["runs"]],
        "rows": rows,
        "missing": [{"env_id": e, "algo": a, "reason": why} for e, a, why in outcome.skipped],
    }
    return write_report(out_dir, "random_start.html", context, summary)


def run_random_start(
    profile: str = "reduced",
    store: Path = Path("runs"),
    out_dir: Path | None = None,
    envs: list[str] | None = None,
    options: GridOptions | None = None,
) -> Path | None:
    """Train what the study lacks (the random-start runs; the default start's are Fig. 3's;
    only on ``envs`` when given) and write its report from every run of the study."""
    from replicate.figures.training import train_and_report
    from replicate.grids.experiments import GridOptions

    out = Path(out_dir or report_dir(profile, NAME))
    return train_and_report(
        random_start_grid(profile),
        [],
        profile,
        command(profile),
        Path(store),
        out,
        lambda outcome, where: write_random_start_report(outcome, profile, where),
        envs=envs,
        options=options or GridOptions(),
    )


def rebuild(profile: str, store: Path, out_dir: Path, seeds: int | None) -> Path | None:
    outcome = stored_study(profile, store, seeds)
    return None if outcome is None else write_random_start_report(outcome, profile, out_dir)


def describe(summary: dict[str, Any]) -> dict[str, str]:
    return {
        "covers": "SAC with the SAC authors' random start against the default start",
        "budget": budget_words([row["steps"] for row in summary["rows"]]),
        "seeds": seed_words([len(row["random"]) for row in summary["rows"]]),
    }


# the command that trains the comparison and writes its report


def _declare_command(sub: Any) -> None:
    start = sub.add_parser(
        "random-start",
        help="SAC with the SAC authors' random start against the default start",
        description="Train SAC on HalfCheetah-v5 and Ant-v5 with 10,000 uniform-random "
        "start steps, from the seeds of the profile's Fig. 3 SAC runs (only runs missing "
        "from the store), and write reports/<profile>/random-start/index.html: each env's "
        "paired difference in final return and area under the curve.",
        formatter_class=HelpFormatter,
    )
    add_grid_arguments(
        start,
        "report directory (default: reports/<profile>/random-start)",
        profile_default="reduced",
        seeds_help=None,
    )
    start.add_argument(
        "--envs",
        nargs="+",
        default=None,
        metavar="ENV",
        help="train only on these of the study's envs (the report still shows every "
        "env's stored runs)",
    )


def _run_command(args: argparse.Namespace) -> int:
    return run_figure(run_random_start, args)


FIGURE = FigureReport(NAME, rebuild, describe, Command(NAME, _declare_command, _run_command))
