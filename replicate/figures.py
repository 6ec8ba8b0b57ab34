"""Figures drawn from the run store with seaborn; returned as PNG bytes for embedding."""

from __future__ import annotations

import io
from dataclasses import dataclass

import matplotlib

matplotlib.use("Agg")  # no display is ever needed
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import seaborn as sns  # noqa: E402


@dataclass
class CurveBand:
    """Mean learning curve of one algorithm on one env with its confidence band."""

    algo: str
    env_id: str
    steps: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    n_runs: int


def steps_label(steps: float) -> str:
    """An env-step count as a short tick label: 0, 50k, 200k, 1M, 1.5M."""
    steps = round(float(steps), 6) + 0.0  # no "-0" or "1e-11" from a tick's float noise
    if abs(steps) >= 1_000_000:
        return f"{steps / 1_000_000:g}M"
    if abs(steps) >= 1000:
        return f"{steps / 1000:g}k"
    return f"{steps:g}"


def format_steps_axis(ax) -> None:
    """Label ``ax``'s x axis in env steps with short ticks (50k, not 50000), which stay
    apart on narrow panels."""
    ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: steps_label(value)))
    ax.set_xlabel("env steps")


def panel_order(envs: list[str], env_order: list[str]) -> list[str]:
    """The distinct ``envs`` in ``env_order``'s order, those it lacks after them as they
    come."""
    present = list(dict.fromkeys(envs))
    return [e for e in env_order if e in present] + [e for e in present if e not in env_order]


def learning_curves_png(bands: list[CurveBand], reference_lines: dict[str, float],
                        title: str,
                        reference_points: dict[str, list[tuple[int, float, float]]] | None = None,
                        env_order: list[str] | None = None) -> bytes:
    """One panel per env, one line per algorithm (mean) with a shaded 95% CI band.

    ``reference_lines`` maps env id to the demonstrations' mean return, drawn dashed;
    ``reference_points`` to published SAC's (steps, mean, sd), drawn as points with bars;
    ``env_order`` orders the panels (the paper's order), envs it lacks going last.
    """
    sns.set_theme(style="whitegrid", context="notebook")
    envs = panel_order([b.env_id for b in bands], env_order or [])
    algos = list(dict.fromkeys(b.algo for b in bands))
    palette = dict(zip(algos, sns.color_palette("colorblind", len(algos)), strict=True))
    fig, axes = plt.subplots(1, len(envs), figsize=(5.2 * len(envs), 3.8), squeeze=False)
    for ax, env_id in zip(axes[0], envs, strict=True):
        frame = pd.DataFrame([
            {"env steps": s, "return": m, "algorithm": f"{b.algo} (n={b.n_runs})"}
            for b in bands if b.env_id == env_id for s, m in zip(b.steps, b.mean, strict=True)])
        hue_palette = {f"{b.algo} (n={b.n_runs})": palette[b.algo]
                       for b in bands if b.env_id == env_id}
        sns.lineplot(data=frame, x="env steps", y="return", hue="algorithm", ax=ax,
                     palette=hue_palette, errorbar=None, linewidth=1.8)
        for b in bands:
            if b.env_id == env_id:
                ax.fill_between(b.steps, b.low, b.high, color=palette[b.algo], alpha=0.2,
                                linewidth=0)
        if env_id in reference_lines:
            ax.axhline(reference_lines[env_id], color="0.3", linestyle="--", linewidth=1,
                       label="demonstrations")
        published = (reference_points or {}).get(env_id)
        if published:
            xs, ys, sds = zip(*published)
            ax.errorbar(xs, ys, yerr=sds, fmt="D", color="0.15", markersize=4, capsize=2,
                        linewidth=0.8, label="published SAC (Tianshou, -v3)")
        ax.set_title(env_id)
        format_steps_axis(ax)
        ax.legend(fontsize=8, loc="best")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return png_bytes(fig)


def draw_iqm(ax, iqm: dict[str, tuple[float, float, float]], palette: dict, xlabel: str) -> None:
    """One row per algorithm: its IQM with the CI as a horizontal bar."""
    algos = list(iqm)
    for row, algo in enumerate(algos):
        value, low, high = iqm[algo]
        ax.errorbar([value], [row], xerr=[[value - low], [high - value]], fmt="o",
                    color=palette[algo], capsize=4)
    ax.set_yticks(range(len(algos)), algos)
    ax.set_xlabel(xlabel)


def draw_profiles(ax, taus: np.ndarray,
                  profiles: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
                  palette: dict, xlabel: str) -> None:
    """Performance profiles (fraction of runs above each score) with CI bands."""
    for algo, (value, low, high) in profiles.items():
        ax.plot(taus, value, color=palette[algo], label=algo, linewidth=1.8)
        ax.fill_between(taus, low, high, color=palette[algo], alpha=0.2, linewidth=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("fraction of runs above tau")


def png_bytes(fig: plt.Figure) -> bytes:
    """The figure as PNG (the reports embed it), closed afterwards."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return buffer.getvalue()


def aggregate_png(iqm: dict[str, tuple[float, float, float]], taus: np.ndarray,
                  profiles: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> bytes:
    """Left: IQM of normalised final scores with CIs. Right: performance profiles (fraction
    of runs above each normalised score) with CI bands."""
    sns.set_theme(style="whitegrid", context="notebook")
    palette = dict(zip(iqm, sns.color_palette("colorblind", len(iqm)), strict=True))
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 3.6))
    draw_iqm(left, iqm, palette, "IQM of final score / demonstrations' return")
    draw_profiles(right, taus, profiles, palette,
                  "score tau (final return / demonstrations' return)")
    right.legend(fontsize=8)
    fig.tight_layout()
    return png_bytes(fig)


def paired_curves_png(panels: list[tuple[int, dict[str, tuple[np.ndarray, ...]]]],
                      title: str) -> bytes:
    """One panel per seed, one line per algorithm: the paired runs of Fig. 4, from (steps,
    evaluation returns[, training episodes' returns, drawn dotted where recorded])."""
    sns.set_theme(style="whitegrid", context="notebook")
    algos = sorted({algo for _, curves in panels for algo in curves})
    palette = dict(zip(algos, sns.color_palette("colorblind", len(algos)), strict=True))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4), squeeze=False)
    for ax, (seed, curves) in zip(axes[0], panels, strict=True):
        for algo, (steps, returns, *earned) in sorted(curves.items()):
            ax.plot(steps, returns, color=palette[algo], label=algo, linewidth=1.8)
            if earned and np.isfinite(earned[0]).any():
                ax.plot(steps, earned[0], color=palette[algo], linestyle=":", linewidth=1.1)
        ax.set_title(f"seed {seed}")
        format_steps_axis(ax)
        ax.set_ylabel("return")
        ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return png_bytes(fig)
