"""The threshold ablation's report: final return and area under the curve against T2 with
their intervals, the curves and guided shares of each T2, the share of an untrained agent's
states each T2 admits, the check that T2 = 0 equals SAC, and the MuJoCo T2 rule's standing."""

from __future__ import annotations

import base64
import math
import warnings
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from replicate.figures.ablation_grid import (
    ALWAYS,
    Cell,
    area_under_curve,
    threshold_label,
    threshold_spacing,
)
from replicate.grids import drl_eg_settings
from replicate.grids.profiles import GridOutcome, Profile
from replicate.stats import t_mean
from replicate.store.provenance import portable_path
from replicate.store.runs import Run


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

    from replicate.figures.plots import algo_color

    if n == 1:
        return [algo_color("drl-eg")]
    return sns.blend_palette(["#f4b183", algo_color("drl-eg"), "#3d1500"], n)


def tick_label(label: str) -> str:
    """A T2 setting's label as a short tick on two lines ('4x' over '(2.6)'; the axis label
    says what the multiple is of), so that neighbouring ticks stay apart."""
    return label.replace(" spacing (", "\n(").replace(" (", "\n(")


def _figure(rows: list[dict[str, Any]], sac_final: float | None, sac_auc: float | None) -> bytes:
    from matplotlib.lines import Line2D

    from replicate.figures.plots import algo_color, panel_grid, png_bytes, set_theme, shared_legend

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

    from replicate.figures.plots import (
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
    from replicate.reports.pages import mujoco_threats, write_report

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
        # the runs' revisions alone: the revision that wrote the page is not one of them
        "revisions": sorted({r.provenance["git_revision"] for c in cells for r in c.runs}),
        "t2_rule": t2_rule,
        "rule_in_force": drl_eg_settings.MUJOCO_T2_RULE,
        # under every T2 of the sweep, so no single guided share stands for it
        "threats": mujoco_threats([r for c in cells for r in c.runs] + sac_runs, guidance=False),
    }
    summary = {
        "profile": profile.name,
        "env_id": env_id,
        "spacing": spacing,
        "rows": rows,
        "zero_threshold_equals_sac": context["zero_check"],
        "sac_final_mean": sac_final,
        "sac_runs": context["sac_runs"],
        "study_name": study_name,
        "run_ids": [run for row in rows for run in row["runs"]] + context["sac_runs"],
        "failed": [{"run_id": i, "reason": why} for i, why in failed],
        "t2_rule": t2_rule,
        "steps": context["steps"],
        "threats": context["threats"],
        "generated": context["generated"],
    }
    return write_report(out_dir, "ablation.html", context, summary)
