"""Reports: statistics over the run store, the claims, and a self-contained HTML page."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable

import numpy as np

from replicate.claims.checks import Group
from replicate.claims.judge import claim_envs, judge_claims, label
from replicate.claims.confirm_judge import confirmatory_results
from replicate.claims.declaration import declaration_version, load_declaration, trained_before
from replicate.claims.groups import READINGS, claim_groups
from replicate.store.measures import DEFAULT_DECLARATION
from replicate.grids.profiles import PAPER_SEEDS_FIG3, Profile
from replicate.claims.published import published_points
from replicate.stats import (
    probability_of_improvement,
    stratified_bootstrap_ci,
    t_mean,
)
from replicate.store.runs import Run
from replicate.reports.templating import report_environment, step_share
from replicate.reports.words import seed_words

REPORT_SEED = 20_260_101  # the bootstrap's own stream: reports rebuild identically


def drl_eg_improvement(
    scores: dict[str, np.ndarray], algos: list[str], rng: np.random.Generator
) -> list[dict[str, Any]]:
    """P(DRL-EG > each other algorithm) on (runs, tasks) scores, with stratified-bootstrap
    CIs; empty without DRL-EG."""
    if "drl-eg" not in scores:
        return []
    rows = []
    for other in algos:
        if other != "drl-eg":
            est = stratified_bootstrap_ci(
                probability_of_improvement, (scores["drl-eg"], scores[other]), rng
            )
            rows.append(
                {
                    "other": other,
                    "value": float(est.value),
                    "low": float(est.low),
                    "high": float(est.high),
                }
            )
    return rows


def published_rows(
    groups: dict[tuple[str, str], Group],
    budgets: dict[str, int],
    envs: set[str] | None = None,
) -> list[dict[str, Any]]:
    """Our SAC beside published SAC at every published budget within ours, and the
    evaluation at those steps of the run that trained the env's expert (the harness's
    twin-Q SAC, one seed), where it trained that far; for ``envs`` (default: the groups')."""
    from replicate.experts import expert_training_curve

    rows = []
    for env_id in sorted({e for e, _ in groups} if envs is None else envs):
        if env_id not in budgets:
            continue
        sac = groups.get((env_id, "sac"))
        points = published_points(env_id, budgets[env_id])
        expert_run = expert_training_curve(env_id) if points else None
        for point in points:
            ours = None
            if sac is not None and sac.steps is not None and point.steps in set(sac.steps):
                column = sac.curves[:, list(sac.steps).index(point.steps)]
                est = t_mean(column)
                ours = {"mean": est.value, "low": est.low, "high": est.high, "n": len(column)}
            expert = None
            if expert_run is not None and point.steps in expert_run["steps"]:
                expert = {k: expert_run[k] for k in ("algo", "seed", "best_of")}
                expert["return"] = expert_run["returns"][expert_run["steps"].index(point.steps)]
            rows.append(
                {
                    "env_id": env_id,
                    "steps": point.steps,
                    "mean": point.mean,
                    "std": point.std,
                    "label": point.label,
                    "source": point.source,
                    "family": point.family,
                    "settings": point.about.settings,
                    "statistic": point.about.statistic,
                    "ours": ours,
                    "expert_run": expert,
                }
            )
    return rows


def summary_run_ids(summary: dict[str, Any]) -> list[str]:
    """The run directories a report's ``summary.json`` names: its ``run_ids``, which every
    report writes (none for a summary without them)."""
    return list(summary.get("run_ids", []))


def runs_missing_for(report_dir: Path, store: Path) -> list[str]:
    """The runs an existing report names that the store lacks: rebuilding it would lose them."""
    summary_file = Path(report_dir) / "summary.json"
    if not summary_file.is_file():
        return []
    try:
        summary = json.loads(summary_file.read_text())
        named = summary_run_ids(summary)
    except (ValueError, TypeError, KeyError, AttributeError):
        return []  # torn or foreign: it names no run we could lose by rebuilding
    return [r for r in named if not (Path(store) / r / "curve.csv").is_file()]


def write_unless_fewer(
    out_dir: Path, store: Path, build: Callable[[Path], Path | None]
) -> tuple[Path | None, str | None]:
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
        after = (
            len(summary_run_ids(json.loads((trial / "summary.json").read_text())))
            if written is not None
            else 0
        )
        if after < before:
            return None, (
                f"{out_dir}: left as it is; {len(missing)} of the {before} runs it "
                f"names are not in {store} (e.g. {missing[0]}), and the store gives "
                f"{after}"
            )
        old = out_dir.with_name(f".{out_dir.name}.old")
        shutil.rmtree(old, ignore_errors=True)
        os.replace(out_dir, old)
        os.replace(trial, out_dir)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(trial, ignore_errors=True)
    return out_dir / "index.html", (
        f"from {after} runs; {len(missing)} of the {before} it named are no longer in {store}"
    )


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

    return (json.dumps(strict(summary), indent=2, default=float, allow_nan=False) + "\n").encode()


def write_report(
    out_dir: Path, template: str, context: dict[str, Any], summary: dict[str, Any]
) -> Path:
    """A report: ``template`` rendered with ``context`` as ``out_dir/index.html`` and
    ``summary`` beside it as summary.json, each replaced atomically; the page's path."""
    out_dir = Path(out_dir)
    html = report_environment().get_template(template).render(**context)
    _atomic_write(out_dir / "index.html", html.encode())
    _atomic_write(out_dir / "summary.json", summary_bytes(summary))
    return out_dir / "index.html"


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".partial")
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)
    os.chmod(tmp, 0o644)  # mkstemp creates 0600; reports are meant to be read
    os.replace(tmp, path)


def demo_returns(runs: list[Run]) -> dict[str, float]:
    """The demonstrations' mean return per env, from the runs that used them."""
    return {
        run.spec["env_id"]: run.provenance["demos"]["expert_return_mean"]
        for run in runs
        if run.provenance.get("demos")
    }


def judging_profile(claim_envs: tuple[str, ...]) -> str | None:
    """The smallest profile whose Fig. 3 budget covers ``claim_envs`` and means something:
    where a claim the current profile cannot judge is judged."""
    from replicate.grids.profiles import PROFILES

    return next(
        (p.name for p in PROFILES.values() if p.meaningful and set(claim_envs) <= set(p.steps)),
        None,
    )


def _declaration_record(runs: list[Run]) -> dict[str, Any]:
    """The declaration a ledger judged with: its file, version, and how many of the
    ledger's runs were trained before that version."""

    version = declaration_version(DEFAULT_DECLARATION)
    started = [r.provenance.get("started_utc") for r in runs]
    return {
        "file": f"replicate/declarations/{DEFAULT_DECLARATION.name}",
        "commit": version.commit,
        "date": version.date,
        "version": version.short,
        "runs": len(runs),
        "trained_before": trained_before(started, version) if version.commit else len(runs),
    }


def _robustness(
    runs: list[Run], fig4_runs: list[Run], profile: Profile, claims: list[dict[str, Any]]
) -> None:
    """Each judged claim's verdict under the single last evaluation and under the training
    episodes' returns, beside the declared reading (``claim["robustness"]``)."""

    specs = {c.id: c for c in load_declaration().claims}
    judged = [c for c in claims if not c["verdict"].startswith("not judged")]
    for reading in READINGS[1:]:
        groups = claim_groups(runs, reading)
        fig4 = claim_groups(fig4_runs, reading) if fig4_runs else None
        by_id = {c["id"]: c for c in judge_claims(groups, True, set(profile.steps), fig4)}
        for claim in judged:
            these = (fig4 or {}) if claim["runs"] == "fig4" else groups
            read = {
                (check.env, algo)
                for check in specs[claim["id"]].checks
                for algo in (check.algo, check.other)
                if algo
            }
            left_out = sorted(f"{label(a)} on {e}" for e, a in read if (e, a) not in these)
            verdict = by_id[claim["id"]]["verdict"]
            if left_out:
                named = ", ".join(left_out[:3]) + (", ..." if len(left_out) > 3 else "")
                verdict = (
                    f"not available: the runs of {len(left_out)} of the {len(read)} cells it "
                    f"reads record no training-episode returns ({named})"
                )
            claim.setdefault("robustness", {})[reading] = verdict


def ledger(runs: list[Run], fig4_runs: list[Run], profile: Profile) -> list[dict[str, Any]]:
    """The profile's one verdict per claim, judged with the declaration: those on Fig. 3's
    runs from ``runs``, those on Fig. 4's paired runs from ``fig4_runs``; a claim on envs
    outside the profile's budget names the report that judges it (``where``: a link within
    reports/)."""
    from replicate.grids.profiles import report_dir

    declaration = load_declaration()
    envs_of = claim_envs(declaration)
    fig3_runs_absent = not runs  # the Fig. 4 report asks for its claims alone
    stores = {r.path.parent for r in runs + fig4_runs}
    confirmed = {}
    for store in sorted(stores) if profile.meaningful else []:
        confirmed.update(confirmatory_results(profile.name, store))
    claims = judge_claims(
        claim_groups(runs),
        profile.meaningful,
        judged_envs=set(profile.steps),
        fig4_groups=claim_groups(fig4_runs) if fig4_runs else None,
        declaration=declaration,
        confirmed=confirmed,
    )
    record = _declaration_record(runs + fig4_runs)
    for claim, spec in zip(claims, declaration.claims):
        claim["runs"] = spec.runs
        claim["declaration"] = record
        claim["where"] = None
        if claim["verdict"].startswith("not judged at this profile"):
            other = judging_profile(envs_of[claim["id"]])
            if other:
                # reports link each other within the standard layout of reports/
                here = report_dir(profile.name, "fig4" if fig3_runs_absent else "fig3")
                target = Path(os.path.relpath(report_dir(other, spec.runs) / "index.html", here))
                claim["verdict"] += f": see the {other} profile's report"
                claim["where"] = f"{target.as_posix()}#claim-{claim['id']}"
    if profile.meaningful:
        _robustness(runs, fig4_runs, profile, claims)
    return claims


MUJOCO_ENVS = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")


def mujoco_threats(
    runs: list[Run], paper_seeds: int | None = None, guidance: bool = True
) -> list[str]:
    """``threats_to_validity`` for a report that is not Fig. 3 (the comparison, an ablation):
    our SAC against published SAC at its runs' budget (an ablation's runs are several cells
    per env: only SAC's are grouped)."""
    budgets = {r.spec["env_id"]: int(r.spec["total_steps"]) for r in runs}
    sac = claim_groups([r for r in runs if r.spec["algo"] == "sac"])
    envs = {r.spec["env_id"] for r in runs}
    return threats_to_validity(runs, published_rows(sac, budgets, envs), paper_seeds, guidance)


def sac_standing(published: list[dict[str, Any]]) -> list[str]:
    """Per env, at the largest step where both exist, how our SAC stands against V-network
    SAC (the same algorithm) and against twin-Q SAC, in words from the numbers."""
    from replicate.claims.published import compare_with_published

    lines = []
    for env_id in sorted({p["env_id"] for p in published if p.get("ours")}):
        steps = max(p["steps"] for p in published if p["env_id"] == env_id and p.get("ours"))
        ours = next(
            p["ours"]["mean"]
            for p in published
            if p["env_id"] == env_id and p["steps"] == steps and p.get("ours")
        )
        line = compare_with_published(env_id, steps, ours)
        if line:
            lines.append(line)
    return lines


def threats_to_validity(
    runs: list[Run],
    published: list[dict[str, Any]],
    paper_seeds: int | None = PAPER_SEEDS_FIG3,
    guidance: bool = True,
    sac_start: str | None = None,
) -> list[str]:
    """What a reviewer must weigh before reading a MuJoCo verdict, from the runs: budget and
    seeds against the paper's, how much DRL-EG's guider acted, how far the demonstrations
    fall short of the experts' targets, our SAC against published SAC at the same steps, and
    ``sac_start`` (a line on how our SAC starts) when given. Empty without MuJoCo runs."""
    from replicate.claims.published import EXPERT_TARGETS

    mujoco = [r for r in runs if r.spec["env_id"] in MUJOCO_ENVS]
    if not mujoco:
        return []
    steps = sorted({int(r.spec["total_steps"]) for r in mujoco})
    # a cell is one spec but for its seed (an ablation's T2 points are cells of their own)
    cells = defaultdict(int)
    for run in mujoco:
        cells[
            json.dumps(
                {k: v for k, v in run.spec.items() if k not in ("seed", "spec_hash")},
                sort_keys=True,
            )
        ] += 1
    counts = sorted(set(cells.values()))
    threats = [
        f"Budget and seeds: {' and '.join(f'{s:,}' for s in steps)} env steps per MuJoCo "
        f"run, where the paper's text states no budget (the harness assumes 1M); "
        f"{seed_words(counts)} per cell"
        + (f", where the paper shows {paper_seeds}." if paper_seeds else ".")
    ]
    shares = defaultdict(list)
    for run in mujoco if guidance else []:
        if run.spec["algo"] == "drl-eg":
            shares[run.spec["env_id"]].append(run.guided_share)
    if shares:
        per_env = "; ".join(
            f"{env_id} " + "-".join(dict.fromkeys((step_share(min(v)), step_share(max(v)))))
            for env_id, v in sorted(shares.items())
        )
        threats.append(
            "Guidance under the chosen T2: DRL-EG's guider took this share of the "
            f"training steps ({per_env}); where it rarely acts, DRL-EG is close to "
            "SAC by construction."
        )
    short = []
    for env_id, value in sorted(demo_returns(mujoco).items()):
        target = EXPERT_TARGETS.get(env_id)
        if target and value < target:
            short.append(
                f"{env_id} {value:.0f} against {target:.0f} ({1 - value / target:.0%} short)"
            )
    if short:
        threats.append(
            "Demonstrations below the experts' targets (what published twin-Q SAC "
            "reaches at 1M steps): " + "; ".join(short) + ". Claim 3's 'near the "
            "demonstrations' is judged against these returns."
        )
    standing = sac_standing(published)
    if standing:
        threats.append(
            "Our SAC against published SAC at the same steps: "
            + "; ".join(standing)
            + ". Published runs used -v1 to -v3 envs and their own settings "
            "(the Fig. 3 report's 'Our SAC against published SAC' lists them)."
        )
    if sac_start:
        threats.append(sac_start)
    return threats
