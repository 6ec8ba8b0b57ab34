"""Figures drawn from the run store; returned as PNG bytes for embedding in the reports.

Every figure is drawn for the reports' content column: ``FIGURE_WIDTH_IN`` wide, which the
page shows at about 100 CSS px per inch, saved at ``DPI`` so that it stays sharp on screens
of twice that pixel density. An algorithm has one colour in every figure (``ALGO_COLORS``);
legends sit outside the curves, in a free cell of the panel grid or below it.
"""

from __future__ import annotations

import io
import json
import math
import zlib
from dataclasses import dataclass, field
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")  # no display is ever needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import seaborn as sns  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402

from replicate.stats import CONFIDENCE  # noqa: E402

FIGURE_WIDTH_IN = 11.0  # the reports' content column is 1100 CSS px wide
DISPLAY_PX_PER_IN = 100  # the figure at the column's width: 100 CSS px per inch
DPI = 2 * DISPLAY_PX_PER_IN  # two device pixels per CSS pixel: sharp at 2x pixel density
FIG3_COLUMNS = 2  # panels side by side in Fig. 3 and Fig. 4: about 550 px each on the page

# One colour per algorithm, whatever figure or report it is drawn in: Okabe and Ito's
# colour-blind safe hues for Fig. 3's algorithms, darker shades of a family's colour for
# its variants.
ALGO_COLORS: dict[str, str] = {
    "sac": "#0072b2",  # blue
    "ppo": "#009e73",  # bluish green
    "ppo-bc": "#56b4e9",  # sky blue
    "ddpgfd": "#e69f00",  # orange
    "drl-eg": "#d55e00",  # vermillion
    "drl-eg-gmm": "#cc79a7",  # reddish purple
    "ibrl": "#1a1a1a",  # near black
    "rlpd": "#6a3d9a",  # violet
    "jsrl": "#9e9a00",  # olive
    "drl-eg-twin-q": "#8c2d04",  # dark vermillion
    "sac-twin-q": "#00476e",  # dark blue
}
# An algorithm the table lacks gets one of these, fixed by its name, so that it too keeps
# its colour from figure to figure.
SPARE_COLORS = ("#17becf", "#e7298a", "#1b9e77", "#a6761d", "#7570b3", "#666600")
REFERENCE_COLOR = "0.25"  # demonstrations, published points: no algorithm's colour


def algo_color(algo: str) -> str:
    """The colour ``algo`` has in every figure."""
    if algo in ALGO_COLORS:
        return ALGO_COLORS[algo]
    return SPARE_COLORS[zlib.crc32(algo.encode()) % len(SPARE_COLORS)]


def algo_order(algos: Sequence[str]) -> list[str]:
    """The distinct ``algos`` in the palette's order (legends list them alike in every
    figure), those it lacks after them alphabetically."""
    present = set(algos)
    return [a for a in ALGO_COLORS if a in present] + sorted(present - set(ALGO_COLORS))


@dataclass
class CurveBand:
    """Learning curve of one algorithm on one env: the mean over seeds with its confidence
    band, and each seed's own curve (``per_seed``: runs x steps, in ``seeds``' order)."""

    algo: str
    env_id: str
    steps: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    n_runs: int
    per_seed: np.ndarray | None = None
    seeds: list[int] = field(default_factory=list)


def steps_label(steps: float) -> str:
    """An env-step count as a short tick label: 0, 50k, 200k, 1M, 1.5M."""
    steps = round(float(steps), 6) + 0.0  # no "-0" or "1e-11" from a tick's float noise
    if abs(steps) >= 1_000_000:
        return f"{steps / 1_000_000:g}M"
    if abs(steps) >= 1000:
        return f"{steps / 1000:g}k"
    return f"{steps:g}"


def format_steps_axis(ax: Axes) -> None:
    """Label ``ax``'s x axis in env steps with short ticks (50k, not 50000), which stay
    apart on narrow panels."""
    ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: steps_label(value)))
    ax.set_xlabel("env steps")


def panel_order(envs: list[str], env_order: list[str]) -> list[str]:
    """The distinct ``envs`` in ``env_order``'s order, those it lacks after them as they
    come."""
    present = list(dict.fromkeys(envs))
    return [e for e in env_order if e in present] + [e for e in present if e not in env_order]


def set_theme() -> None:
    """The look every figure shares."""
    sns.set_theme(style="whitegrid", context="notebook")
    plt.rcParams.update(
        {
            "legend.fontsize": 11,
            "axes.titlesize": 12,
            "figure.titlesize": 13,
            "legend.title_fontsize": 11,
        }
    )


def panel_grid(
    n_panels: int, columns: int, panel_height: float, legend_height: float = 0.0
) -> tuple[plt.Figure, list[Any], Any]:
    """A figure of ``n_panels`` panels, ``columns`` a row, at the content column's width:
    (figure, the panels' axes, the first free cell's axes for a legend or None when the
    grid is full). ``legend_height`` (inches) is added below for a legend a full grid
    needs."""
    rows = math.ceil(n_panels / columns)
    free = rows * columns > n_panels
    height = rows * panel_height + (0.0 if free else legend_height)
    fig = plt.figure(figsize=(FIGURE_WIDTH_IN, height), layout="constrained")
    axes = list(fig.subplots(rows, columns, squeeze=False).ravel())
    for ax in axes[n_panels:]:
        ax.axis("off")
    return fig, axes[:n_panels], (axes[n_panels] if free else None)


def shared_legend(
    fig: plt.Figure,
    handles: list[Any],
    labels: list[str],
    slot: Any = None,
    columns: int | None = None,
) -> None:
    """One legend for all panels: centred in ``slot`` (a free cell of the grid) when there
    is one, else below the panels, ``columns`` entries a row (all of them by default)."""
    if slot is not None:
        slot.legend(
            handles, labels, loc="center", frameon=False, ncols=columns or 1, handlelength=2.6
        )
    else:
        fig.legend(
            handles,
            labels,
            loc="outside lower center",
            frameon=False,
            ncols=columns or len(labels),
            handlelength=2.6,
        )


def env_panels(
    runs: Sequence[Any], panel_height: float, ylabel: str
) -> tuple[plt.Figure, list[tuple[Axes, list[Any]]], Any]:
    """The figure of a report on runs: the shared look, one panel per env of ``runs``
    (sorted), each titled with its env, its y axis labelled and its x axis in env steps:
    (figure, [(panel, that env's runs)], the free cell for a legend or None)."""
    set_theme()
    envs = sorted({r.spec["env_id"] for r in runs})
    fig, axes, slot = panel_grid(len(envs), FIG3_COLUMNS, panel_height, legend_height=0.6)
    panels = []
    for ax, env_id in zip(axes, envs, strict=True):
        ax.set_title(env_id)
        ax.set_ylabel(ylabel)
        format_steps_axis(ax)
        panels.append((ax, [r for r in runs if r.spec["env_id"] == env_id]))
    return fig, panels, slot


def finished_png(
    fig: plt.Figure, handles: list[Any], labels: list[str], slot: Any, title: str
) -> bytes:
    """The shared legend and the title added, the figure as PNG bytes."""
    shared_legend(fig, handles, labels, slot)
    fig.suptitle(title)
    return png_bytes(fig)


def algo_handle(algo: str, **style: Any) -> Line2D:
    """A legend entry's line in ``algo``'s colour."""
    return Line2D([], [], color=algo_color(algo), linewidth=style.pop("linewidth", 2.2), **style)


def seed_note(counts: dict[str, int]) -> str:
    """How many seeds each algorithm's curve has on one panel: '5 seeds each', or the usual
    count and the algorithms that differ ('3 seeds; ppo, ppo-bc: 5')."""
    values = list(counts.values())
    usual = max(sorted(set(values), reverse=True), key=values.count)
    noun = "seed" if usual == 1 else "seeds"
    others: dict[int, list[str]] = {}
    for algo in algo_order(list(counts)):
        if counts[algo] != usual:
            others.setdefault(counts[algo], []).append(algo)
    if not others:
        return f"{usual} {noun} each" if len(counts) > 1 else f"{usual} {noun}"
    return f"{usual} {noun}; " + "; ".join(
        f"{', '.join(algos)}: {n}" for n, algos in sorted(others.items())
    )


# Published SAC on the curves: the same algorithm as ours open, modern twin-Q SAC filled.
PUBLISHED_MARKERS = {"V-network SAC": ("o", "white"), "twin-Q SAC": ("D", "0.1")}
PUBLISHED_LABELS = {
    "V-network SAC": "published V-network SAC (Spinning Up, Coach; -v2)",
    "twin-Q SAC": "published twin-Q SAC (Tianshou, -v3)",
}


def learning_curves_png(
    bands: list[CurveBand],
    reference_lines: dict[str, float],
    title: str,
    reference_points: dict[str, list[tuple[int, float, float, str]]] | None = None,
    env_order: list[str] | None = None,
    confidence: float = CONFIDENCE,
) -> bytes:
    """Fig. 3: one panel per env, ``FIG3_COLUMNS`` a row; per algorithm each seed's curve
    as a thin line under the mean over seeds (thick) with its ``confidence`` t-interval
    band; one legend for all panels.

    ``reference_lines`` maps env id to the demonstrations' mean return, drawn dashed;
    ``reference_points`` to published SAC's (steps, mean, sd, family), drawn as points with
    bars, one marker per family (``PUBLISHED_MARKERS``: V-network SAC, twin-Q SAC);
    ``env_order`` orders the panels (the paper's order), envs it lacks going last.
    """
    set_theme()
    envs = panel_order([b.env_id for b in bands], env_order or [])
    algos = algo_order([b.algo for b in bands])
    fig, axes, slot = panel_grid(len(envs), FIG3_COLUMNS, 4.0, legend_height=1.0)
    published_families: set[str] = set()
    demos_any = seeds_any = False
    for ax, env_id in zip(axes, envs, strict=True):
        here = sorted((b for b in bands if b.env_id == env_id), key=lambda b: algos.index(b.algo))
        for b in here:
            color = algo_color(b.algo)
            ax.fill_between(b.steps, b.low, b.high, color=color, alpha=0.16, linewidth=0, zorder=1)
            if b.per_seed is not None and len(b.per_seed) > 1:
                seeds_any = True
                for curve in b.per_seed:
                    ax.plot(b.steps, curve, color=color, linewidth=0.8, alpha=0.55, zorder=2)
        for b in here:  # every mean above every seed's line
            ax.plot(b.steps, b.mean, color=algo_color(b.algo), linewidth=2.2, zorder=3)
        if env_id in reference_lines:
            demos_any = True
            ax.axhline(
                reference_lines[env_id],
                color=REFERENCE_COLOR,
                linestyle="--",
                linewidth=1.2,
                zorder=4,
            )
        for family, (marker, face) in PUBLISHED_MARKERS.items():
            published = [p for p in (reference_points or {}).get(env_id, []) if p[3] == family]
            if published:
                published_families.add(family)
                xs, ys, sds = (list(v) for v in zip(*(p[:3] for p in published)))
                sds = [0.0 if sd != sd else sd for sd in sds]  # a source without a spread
                ax.errorbar(
                    xs,
                    ys,
                    yerr=sds,
                    fmt=marker,
                    color="0.1",
                    markerfacecolor=face,
                    markersize=6,
                    capsize=3,
                    linewidth=1.0,
                    zorder=5,
                )
        ax.set_title(
            f"{env_id}\n{seed_note({b.algo: b.n_runs for b in here})}", fontsize=12, linespacing=1.4
        )
        format_steps_axis(ax)
        ax.set_ylabel("return")
    handles = [algo_handle(a) for a in algos]
    labels = list(algos)
    grey = "0.45"
    handles.append(Line2D([], [], color=grey, linewidth=2.2))
    labels.append("mean over seeds")
    if seeds_any:
        handles.append(Line2D([], [], color=grey, linewidth=0.8))
        labels.append("one seed")
    handles.append(Patch(facecolor=grey, alpha=0.3, linewidth=0))
    labels.append(f"{confidence:.0%} t-interval of the mean")
    if demos_any:
        handles.append(Line2D([], [], color=REFERENCE_COLOR, linestyle="--", linewidth=1.2))
        labels.append("demonstrations' mean return")
    for family, (marker, face) in PUBLISHED_MARKERS.items():
        if family in published_families:
            handles.append(
                Line2D(
                    [],
                    [],
                    color="0.1",
                    marker=marker,
                    markerfacecolor=face,
                    linestyle="none",
                    markersize=6,
                )
            )
            labels.append(PUBLISHED_LABELS[family])
    shared_legend(fig, handles, labels, slot, columns=None if slot is not None else 4)
    fig.suptitle(title)
    return png_bytes(fig)


def draw_iqm(ax: Axes, iqm: dict[str, tuple[float, float, float]], xlabel: str) -> None:
    """One row per algorithm: its IQM with the CI as a horizontal bar, in its colour."""
    algos = list(iqm)
    for row, algo in enumerate(algos):
        value, low, high = iqm[algo]
        ax.errorbar(
            [value],
            [row],
            xerr=[[value - low], [high - value]],
            fmt="o",
            color=algo_color(algo),
            capsize=4,
            markersize=7,
            linewidth=2,
        )
    ax.set_yticks(range(len(algos)), algos)
    for label, algo in zip(ax.get_yticklabels(), algos, strict=True):
        label.set_color(algo_color(algo))
    ax.set_ylim(len(algos) - 0.4, -0.6)  # the first algorithm on top, as legends list it
    ax.set_xlabel(xlabel)


def draw_profiles(
    ax: Axes,
    taus: np.ndarray,
    profiles: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
    xlabel: str,
) -> None:
    """Performance profiles (fraction of runs above each score) with CI bands."""
    for algo, (value, low, high) in profiles.items():
        ax.plot(taus, value, color=algo_color(algo), label=algo, linewidth=2)
        ax.fill_between(taus, low, high, color=algo_color(algo), alpha=0.15, linewidth=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("fraction of runs above tau")


PANELS_KEY = "Panels"  # the PNG text entry that says where the panels are


def panel_boxes(fig: plt.Figure) -> list[list[float]]:
    """Where each panel's plotting area lies once laid out: [left, bottom, width, height] as
    fractions of the figure (legend cells, drawn without axes, are not panels)."""
    fig.draw_without_rendering()
    return [[round(v, 4) for v in ax.get_position().bounds] for ax in fig.axes if ax.axison]


def png_bytes(fig: plt.Figure) -> bytes:
    """The figure as PNG at ``DPI`` (the reports embed it), closed afterwards. Its text entry
    ``PANELS_KEY`` records the panels' boxes, so that a test can measure them on the page.

    The image is stored with a palette of 256 colours (a third of the bytes of full colour
    at this density, the difference not visible), the near-whites of the palette made
    white so that the background stays the page's."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    boxes = panel_boxes(fig)
    drawn = io.BytesIO()
    fig.savefig(drawn, format="png", dpi=DPI)
    plt.close(fig)
    image = Image.open(drawn).convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT)
    palette = np.asarray(image.getpalette(), dtype=np.uint8).reshape(-1, 3)
    palette[(palette >= 246).all(axis=1)] = 255
    image.putpalette(palette.ravel().tolist())
    info = PngInfo()
    info.add_text(PANELS_KEY, json.dumps(boxes))
    buffer = io.BytesIO()
    image.save(buffer, format="png", optimize=True, pnginfo=info)
    return buffer.getvalue()


def png_panels(png: bytes) -> list[list[float]]:
    """The panels' boxes a figure from ``png_bytes`` records (fractions of the figure)."""
    from PIL import Image

    return json.loads(Image.open(io.BytesIO(png)).text[PANELS_KEY])


def aggregate_png(
    iqm: dict[str, tuple[float, float, float]],
    taus: np.ndarray,
    profiles: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
) -> bytes:
    """Left: IQM of normalised final scores with CIs. Right: performance profiles (fraction
    of runs above each normalised score) with CI bands."""
    set_theme()
    order = algo_order(list(iqm))
    fig, (left, right), _ = panel_grid(2, 2, 3.8, legend_height=0.6)
    draw_iqm(left, {a: iqm[a] for a in order}, "IQM of final score / demonstrations' return")
    draw_profiles(
        right,
        taus,
        {a: profiles[a] for a in order if a in profiles},
        "score tau (final return / demonstrations' return)",
    )
    shared_legend(fig, [algo_handle(a) for a in order], order)
    return png_bytes(fig)


def paired_curves_png(
    panels: list[tuple[int, dict[str, tuple[np.ndarray, ...]]]], title: str
) -> bytes:
    """Fig. 4: one panel per seed, ``FIG3_COLUMNS`` a row, one line per algorithm: the
    paired runs from (steps, evaluation returns[, training episodes' returns, drawn dotted
    where recorded]); one legend for all panels."""
    set_theme()
    algos = algo_order([algo for _, curves in panels for algo in curves])
    fig, axes, slot = panel_grid(len(panels), FIG3_COLUMNS, 3.4, legend_height=0.9)
    dotted = False
    for ax, (seed, curves) in zip(axes, panels, strict=True):
        for algo in algo_order(list(curves)):
            steps, returns, *earned = curves[algo]
            ax.plot(steps, returns, color=algo_color(algo), linewidth=2, zorder=3)
            if earned and np.isfinite(earned[0]).any():
                dotted = True
                ax.plot(
                    steps, earned[0], color=algo_color(algo), linestyle=":", linewidth=1.3, zorder=2
                )
        ax.set_title(f"seed {seed}")
        format_steps_axis(ax)
        ax.set_ylabel("return")
    handles = [algo_handle(a) for a in algos]
    labels = list(algos)
    if dotted:
        handles += [
            Line2D([], [], color="0.45", linewidth=2),
            Line2D([], [], color="0.45", linewidth=1.3, linestyle=":"),
        ]
        labels += ["deterministic evaluation", "training episodes"]
    shared_legend(fig, handles, labels, slot)
    fig.suptitle(title)
    return png_bytes(fig)
