"""Figures drawn from the run store with seaborn; returned as PNG bytes for embedding."""

from __future__ import annotations

import io
from dataclasses import dataclass

import matplotlib

matplotlib.use("Agg")  # no display is ever needed
import matplotlib.pyplot as plt  # noqa: E402
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


def learning_curves_png(bands: list[CurveBand], reference_lines: dict[str, float],
                        title: str) -> bytes:
    """One panel per env, one line per algorithm (mean) with a shaded 95% CI band.

    ``reference_lines`` maps env id to the demonstrations' mean return, drawn dashed.
    """
    sns.set_theme(style="whitegrid", context="notebook")
    envs = list(dict.fromkeys(b.env_id for b in bands))
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
        ax.set_title(env_id)
        ax.legend(fontsize=8, loc="best")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return buffer.getvalue()
