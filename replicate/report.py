"""Reports: statistics over the run store, the claims, and a self-contained HTML page."""

from __future__ import annotations

import base64
import json
import os
import shutil
import tempfile
from collections import defaultdict
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np

from replicate import provenance
from replicate.profiles import PAPER_BUDGETS, PAPER_SEEDS_FIG3, GridOutcome, Profile
from replicate.figures import CurveBand, aggregate_png, learning_curves_png
from replicate.runner import Run
from replicate.claims import Group, judge_claims
from replicate.published import published_points
from replicate.stats import (CONFIDENCE, bootstrap_mean, interquartile_mean, steps_to_reach,
                             probability_of_improvement, score_profile, stratified_bootstrap_ci,
                             substream)
from replicate.templating import report_environment

REPORT_SEED = 20_260_101  # the bootstrap's own stream: reports rebuild identically


@dataclass
class FinalReturns:
    env_id: str
    algo: str
    seeds: list[int]
    finals: np.ndarray
    mean: float
    low: float
    high: float


def group_runs(runs: list[Run]) -> dict[tuple[str, str], list[Run]]:
    groups: dict[tuple[str, str], list[Run]] = defaultdict(list)
    for run in runs:
        groups[(run.spec["env_id"], run.spec["algo"])].append(run)
    for members in groups.values():
        members.sort(key=lambda r: r.spec["seed"])
    return dict(groups)


def curve_matrix(runs: list[Run]) -> tuple[np.ndarray, np.ndarray]:
    """(steps, returns[runs, steps]) over the evaluation steps that every run shares."""
    common = sorted(set.intersection(*(set(r.curve["step"]) for r in runs)))
    matrix = np.stack([r.curve.set_index("step").loc[common, "return_mean"].to_numpy(float)
                       for r in runs])
    return np.asarray(common), matrix


def summarise(runs: list[Run], seed: int) -> tuple[list[CurveBand], list[FinalReturns]]:
    """Each (env, algorithm)'s curve band and final returns, bootstrapped on the cell's own
    stream."""
    bands, finals = [], []
    for (env_id, algo), members in sorted(group_runs(runs).items()):
        steps, matrix = curve_matrix(members)
        band = bootstrap_mean(matrix, substream(seed, env_id, algo, "curve"))
        bands.append(CurveBand(algo, env_id, steps, band.value, band.low, band.high, len(members)))
        last = matrix[:, -1]
        est = bootstrap_mean(last, substream(seed, env_id, algo, "final"))
        finals.append(FinalReturns(env_id, algo, [r.spec["seed"] for r in members], last,
                                   float(est.value[0]), float(est.low[0]), float(est.high[0])))
    return bands, finals


def claim_groups(runs: list[Run]) -> dict[tuple[str, str], Group]:
    """The runs of each (env, algorithm) as the claims ledger reads them."""
    groups = {}
    for (env_id, algo), members in group_runs(runs).items():
        steps, matrix = curve_matrix(members)
        groups[(env_id, algo)] = Group(env_id, algo, [r.spec["seed"] for r in members],
                                       matrix[:, -1], matrix, steps)
    return groups


def drl_eg_improvement(scores: dict[str, np.ndarray], algos: list[str],
                       rng: np.random.Generator) -> list[dict[str, Any]]:
    """P(DRL-EG > each other algorithm) on (runs, tasks) scores, with stratified-bootstrap
    CIs; empty without DRL-EG."""
    if "drl-eg" not in scores:
        return []
    rows = []
    for other in algos:
        if other != "drl-eg":
            est = stratified_bootstrap_ci(probability_of_improvement,
                                          (scores["drl-eg"], scores[other]), rng)
            rows.append({"other": other, "value": float(est.value), "low": float(est.low),
                         "high": float(est.high)})
    return rows


def aggregate_metrics(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float],
                      rng: np.random.Generator) -> dict[str, Any] | None:
    """IQM, performance profiles and probability of improvement over the envs that have
    demonstrations, on final returns divided by the demonstrations' return (Agarwal et
    al. 2021); every algorithm takes the same number of runs per env (the smallest)."""
    algos = sorted({a for _, a in groups})
    tasks = [e for e in sorted({e for e, _ in groups}) if e in demo_returns
             and all((e, a) in groups for a in algos)]
    if not tasks or not algos:
        return None
    runs = min(len(groups[(e, a)].finals) for e in tasks for a in algos)
    if runs < 2:
        return None
    scores = {a: np.stack([groups[(e, a)].finals[:runs] / abs(demo_returns[e]) for e in tasks],
                          axis=1) for a in algos}
    taus = np.linspace(0.0, 1.2, 49)
    iqm, profiles = {}, {}
    for algo in algos:
        est = stratified_bootstrap_ci(interquartile_mean, (scores[algo],), rng)
        iqm[algo] = (float(est.value), float(est.low), float(est.high))
        prof = stratified_bootstrap_ci(lambda s: score_profile(s, taus), (scores[algo],), rng)
        profiles[algo] = (prof.value, prof.low, prof.high)
    improvement = drl_eg_improvement(scores, algos, rng)
    png = aggregate_png(iqm, taus, profiles)
    return {"tasks": tasks, "runs_per_task": runs, "iqm": iqm, "improvement": improvement,
            "png_b64": base64.b64encode(png).decode()}


REACH_FRACTION = 0.5  # sample efficiency: env steps to half of the demonstrations' return


def efficiency_rows(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float],
                    seed: int) -> list[dict[str, Any]]:
    """Per (env, algorithm) with demonstrations: area under the curve and env steps to reach
    ``REACH_FRACTION`` of the demonstrations' return, each with a bootstrap CI over seeds (on
    the cell's own stream)."""
    def estimate(values: np.ndarray, rng: np.random.Generator) -> dict[str, Any]:
        values = values[np.isfinite(values)]
        if not len(values):
            return {"mean": float("nan"), "low": float("nan"), "high": float("nan"), "n": 0}
        est = bootstrap_mean(values, rng)
        return {"mean": float(est.value[0]), "low": float(est.low[0]),
                "high": float(est.high[0]), "n": int(len(values))}

    rows = []
    for (env_id, algo), group in sorted(groups.items()):
        if env_id not in demo_returns:
            continue
        level = REACH_FRACTION * demo_returns[env_id]
        rows.append({"env_id": env_id, "algo": algo, "n": len(group.seeds),
                     "area": estimate(group.areas, substream(seed, env_id, algo, "area")),
                     "reach": estimate(steps_to_reach(group.steps, group.curves, level),
                                       substream(seed, env_id, algo, "reach")),
                     "level": level})
    return rows


def published_rows(groups: dict[tuple[str, str], Group], budgets: dict[str, int],
                   seed: int) -> list[dict[str, Any]]:
    """Our SAC beside published SAC at every published budget within ours, and the
    evaluation at those steps of the run that trained the env's expert (the harness's
    twin-Q SAC, one seed), where it trained that far."""
    from replicate.experts import expert_training_curve

    rows = []
    for env_id in sorted({e for e, _ in groups}):
        if env_id not in budgets:
            continue
        sac = groups.get((env_id, "sac"))
        points = published_points(env_id, budgets[env_id])
        expert_run = expert_training_curve(env_id) if points else None
        for point in points:
            ours = None
            if sac is not None and sac.steps is not None and point.steps in set(sac.steps):
                column = sac.curves[:, list(sac.steps).index(point.steps)]
                est = bootstrap_mean(column, substream(seed, env_id, "sac", str(point.steps)))
                ours = {"mean": float(est.value[0]), "low": float(est.low[0]),
                        "high": float(est.high[0]), "n": len(column)}
            expert = None
            if expert_run is not None and point.steps in expert_run["steps"]:
                expert = {k: expert_run[k] for k in ("algo", "seed", "best_of")}
                expert["return"] = expert_run["returns"][expert_run["steps"].index(point.steps)]
            rows.append({"env_id": env_id, "steps": point.steps, "mean": point.mean,
                         "std": point.std, "label": point.label, "source": point.source,
                         "ours": ours, "expert_run": expert})
    return rows


def summary_run_ids(summary: dict[str, Any]) -> list[str]:
    """The run directories a report's ``summary.json`` names, whatever the report."""
    if "cells" in summary:  # the comparison with IBRL, RLPD, JSRL
        return [run for cell in summary["cells"] for run in cell["runs"]]
    if "runs" in summary:  # Fig. 3
        return [r["run_id"] for r in summary["runs"]]
    return ([run for row in summary.get("rows", []) for run in row["runs"]]  # Fig. 4, ablations
            + summary.get("sac_runs", []))  # an ablation's SAC reference


def runs_missing_for(report_dir: Path, store: Path) -> list[str]:
    """The runs an existing report names that the store lacks: rebuilding it would lose them."""
    summary_file = Path(report_dir) / "summary.json"
    if not summary_file.is_file():
        return []
    summary = json.loads(summary_file.read_text())
    return [r for r in summary_run_ids(summary) if not (Path(store) / r / "curve.csv").is_file()]


def write_unless_fewer(out_dir: Path, store: Path,
                       build: Callable[[Path], Path | None]) -> tuple[Path | None, str | None]:
    """Write a report with ``build(out_dir)``, unless ``out_dir`` already holds one that names
    runs the store lacks (lost, superseded by runs of a new spec, or trained elsewhere): then
    it is built aside and replaces the old one (two renames: never half old, half new) only
    if it names at least as many runs. Returns the index written (None: nothing written) and,
    when some of the old report's runs were missing, a line that says what happened."""
    out_dir = Path(out_dir)
    missing = runs_missing_for(out_dir, store)
    if not missing:
        return build(out_dir), None
    trial = out_dir.with_name(f".{out_dir.name}.rebuild")
    shutil.rmtree(trial, ignore_errors=True)
    try:
        written = build(trial)
        before = len(summary_run_ids(json.loads((out_dir / "summary.json").read_text())))
        after = (len(summary_run_ids(json.loads((trial / "summary.json").read_text())))
                 if written is not None else 0)
        if after < before:
            return None, (f"{out_dir}: left as it is; {len(missing)} of the {before} runs it "
                          f"names are not in {store} (e.g. {missing[0]}), and the store gives "
                          f"{after}")
        old = out_dir.with_name(f".{out_dir.name}.old")
        shutil.rmtree(old, ignore_errors=True)
        os.replace(out_dir, old)
        os.replace(trial, out_dir)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(trial, ignore_errors=True)
    return out_dir / "index.html", (f"from {after} runs; {len(missing)} of the {before} it "
                                    f"named are no longer in {store}")


def summary_bytes(summary: dict[str, Any]) -> bytes:
    """A report's ``summary.json``: strict JSON (what jq and browsers parse), so a number
    that is not defined (no seed reached a threshold, a CI of one run) is written as null."""
    def strict(value: Any) -> Any:
        if isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, float) and not np.isfinite(value):
            return None
        if isinstance(value, dict):
            return {key: strict(v) for key, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [strict(v) for v in value]
        return value

    return (json.dumps(strict(summary), indent=2, default=float, allow_nan=False)
            + "\n").encode()


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".partial")
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)
    os.chmod(tmp, 0o644)  # mkstemp creates 0600; reports are meant to be read
    os.replace(tmp, path)


def write_figure3_report(outcome: GridOutcome, profile: Profile, out_dir: Path,
                         guidance: list[dict[str, Any]] | None = None) -> Path:
    """Write ``out_dir/index.html`` (self-contained) and ``out_dir/summary.json``;
    ``guidance`` (``experiments.guidance_settings``) is printed beside the claims."""
    runs = outcome.runs
    bands, finals = summarise(runs, REPORT_SEED) if runs else ([], [])
    demo_lines = {}
    demos = {}
    for run in runs:
        info = run.provenance.get("demos")
        if info:
            demo_lines[run.spec["env_id"]] = info["expert_return_mean"]
            demos[info["sha256"]] = dict(info, env_id=run.spec["env_id"])
    groups = claim_groups(runs)
    claims = judge_claims(groups, demo_lines, REPORT_SEED, profile.meaningful)
    aggregate = aggregate_metrics(groups, demo_lines, substream(REPORT_SEED, "aggregate"))
    efficiency = efficiency_rows(groups, demo_lines, REPORT_SEED)
    published = published_rows(groups, profile.steps, REPORT_SEED)
    title = f"Fig. 3 replication, profile '{profile.name}'"
    points = {env_id: [(p.steps, p.mean, p.std) for p in published_points(env_id, steps)
                       if p.source == "tianshou"]
              for env_id, steps in profile.steps.items() if env_id in {b.env_id for b in bands}}
    figure = (base64.b64encode(learning_curves_png(bands, demo_lines, title, points,
                                                   list(profile.steps))).decode()
              if bands else None)
    revisions = sorted({r.provenance["git_revision"] for r in runs})
    first = runs[0].provenance if runs else {}
    budgets = [{"env_id": env_id, "steps": profile.steps[env_id],
                "eval_interval": profile.eval_interval[env_id],
                "eval_episodes": profile.eval_episodes,
                "seeds": {algo: sorted(r.spec["seed"] for r in members)
                          for (env, algo), members in sorted(group_runs(runs).items())
                          if env == env_id},
                "paper": PAPER_BUDGETS.get(env_id, "-")} for env_id in profile.steps]
    context = {
        "title": title, "profile": profile, "paper_seeds": PAPER_SEEDS_FIG3,
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "figure_png_b64": figure, "finals": finals, "claims": claims, "aggregate": aggregate, "budgets": budgets,
        "runs": sorted(runs, key=lambda r: (r.spec["env_id"], r.spec["algo"], r.spec["seed"])),
        "failed": outcome.failed, "skipped": outcome.skipped, "demos": list(demos.values()),
        "versions": first.get("versions", provenance.package_versions()),
        "machine": first.get("machine", provenance.machine()),
        "revisions": revisions or [provenance.git_revision()],
        "train_wall_s": sum(r.provenance["wall_time_s"] for r in runs),
        "grid_wall_s": outcome.wall_time_s, "confidence": CONFIDENCE,
        "efficiency": efficiency, "published": published, "reach_fraction": REACH_FRACTION,
        "guidance": guidance or [],
    }
    env = report_environment()
    html = env.get_template("fig3.html").render(**context)
    out_dir = Path(out_dir)
    _atomic_write(out_dir / "index.html", html.encode())
    summary = {
        "profile": profile.name, "generated": context["generated"], "claims": claims,
        "final_returns": [{"env_id": f.env_id, "algo": f.algo, "seeds": f.seeds,
                           "finals": f.finals.tolist(), "mean": f.mean, "ci95": [f.low, f.high]}
                          for f in finals],
        "runs": [{"run_id": r.path.name, "spec_hash": r.provenance["spec_hash"],
                  "final_return": r.final_return} for r in context["runs"]],
        "failed": [{"run_id": i, "reason": why} for i, why in outcome.failed],
        "skipped": [{"env_id": e, "algo": a, "reason": why} for e, a, why in outcome.skipped],
        "aggregate": None if aggregate is None else {
            k: aggregate[k] for k in ("tasks", "runs_per_task", "iqm", "improvement")},
        "efficiency": efficiency, "published_sac": published, "guidance": guidance or [],
        "git_revisions": context["revisions"],
    }
    _atomic_write(out_dir / "summary.json",
                  summary_bytes(summary))
    return out_dir / "index.html"


def write_figure4_report(outcome: GridOutcome, profile: Profile, env_id: str,
                         out_dir: Path, guidance: list[dict[str, Any]] | None = None) -> Path:
    """Fig. 4: one panel per seed, SAC against DRL-EG from identical initial weights, the
    paired differences, and claim 5 when the env is the paper's (Ant)."""
    from replicate.claims import ANT, budget_note, claim_5, claim_streams
    from replicate.figures import paired_curves_png
    from replicate.stats import paired_difference

    rng = np.random.default_rng(REPORT_SEED)
    by_seed: dict[int, dict[str, Run]] = defaultdict(dict)
    for run in outcome.runs:
        by_seed[run.spec["seed"]][run.spec["algo"]] = run
    pairs = {seed: runs for seed, runs in sorted(by_seed.items()) if len(runs) == 2}
    rows = []
    for seed, runs in pairs.items():
        sac, drl = runs["sac"], runs["drl-eg"]
        rows.append({"seed": seed, "sac": sac.final_return, "drl": drl.final_return,
                     "difference": drl.final_return - sac.final_return,
                     "guided_share": drl.guided_share,
                     # same seed, same initial weights: the step-0 evaluations must agree
                     "same_start": sac.curve["returns"].iloc[0] == drl.curve["returns"].iloc[0],
                     "runs": [sac.path.name, drl.path.name]})
    paired = None
    if len(rows) >= 2:
        estimate, p_value = paired_difference(np.array([r["drl"] for r in rows]),
                                              np.array([r["sac"] for r in rows]), rng)
        paired = {"value": float(estimate.value), "low": float(estimate.low),
                  "high": float(estimate.high), "p_value": p_value}
    claim = None
    if env_id == ANT and pairs:
        groups = claim_groups(outcome.runs)
        claim = claim_5(groups, {}, claim_streams(REPORT_SEED, 5))  # as Fig. 3's ledger
        claim["budget_note"] = budget_note(5, groups)
        if not profile.meaningful:
            claim["verdict"] = "not judged (smoke profile: numbers mean nothing)"
    panels = [(seed, {algo: (run.curve["step"].to_numpy(), run.curve["return_mean"].to_numpy(),
                             run.curve["train_return"].to_numpy(float))
                      for algo, run in runs.items()}) for seed, runs in pairs.items()]
    title = f"Fig. 4 replication on {env_id}, profile '{profile.name}'"
    context = {
        "title": title, "profile": profile, "env_id": env_id, "rows": rows, "paired": paired,
        "claim": claim, "confidence": CONFIDENCE, "failed": outcome.failed,
        "missing": outcome.skipped,
        "figure_png_b64": base64.b64encode(paired_curves_png(panels, title)).decode()
        if panels else None,
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "steps": int(outcome.runs[0].spec["total_steps"]) if outcome.runs else 0,
        "revisions": sorted({r.provenance["git_revision"] for r in outcome.runs}),
        "guidance": guidance or [],
    }
    env = report_environment()
    out_dir = Path(out_dir)
    _atomic_write(out_dir / "index.html", env.get_template("fig4.html").render(**context).encode())
    summary = {"profile": profile.name, "env_id": env_id, "claim": claim, "paired": paired,
               "rows": [dict(r, same_start=bool(r["same_start"])) for r in rows],
               "guidance": guidance or [],
               "missing": [{"env_id": e, "algo": a, "reason": why}
                           for e, a, why in outcome.skipped],
               "failed": [{"run_id": i, "reason": why} for i, why in outcome.failed]}
    _atomic_write(out_dir / "summary.json",
                  summary_bytes(summary))
    return out_dir / "index.html"
