"""Figure helpers: short env-step tick labels and the paper's panel order."""

import matplotlib.pyplot as plt

from replicate.figures.plots import format_steps_axis, panel_order, steps_label
from replicate.grids.profiles import get_profile


def test_steps_label_shortens_thousands_and_millions():
    assert [steps_label(v) for v in (0, 500, 2500, 50_000, 200_000, 1_000_000, 1_500_000)] == [
        "0",
        "500",
        "2.5k",
        "50k",
        "200k",
        "1M",
        "1.5M",
    ]
    assert steps_label(-0.0) == "0" and steps_label(1e-11) == "0"


def test_steps_axis_uses_short_labels():
    fig, ax = plt.subplots()
    format_steps_axis(ax)
    assert ax.xaxis.get_major_formatter()(100_000, 0) == "100k"
    assert ax.get_xlabel() == "env steps"
    plt.close(fig)


def test_panels_follow_the_profile_order_with_unknown_envs_last():
    order = list(get_profile("reduced").steps)
    assert order[0] == "MountainCarContinuous-v0" and order[-1] == "Ant-v5"  # the paper's Table 1
    bands_envs = ["Ant-v5", "Hopper-v5", "Ant-v5", "Other-v0", "MountainCarContinuous-v0"]
    assert panel_order(bands_envs, order) == [
        "MountainCarContinuous-v0",
        "Hopper-v5",
        "Ant-v5",
        "Other-v0",
    ]
    assert panel_order(bands_envs, []) == [
        "Ant-v5",
        "Hopper-v5",
        "Other-v0",
        "MountainCarContinuous-v0",
    ]


# --- one palette, shared legends outside the curves, per-seed lines, readable T2 ticks ---

import types  # noqa: E402

import matplotlib.colors as mcolors  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402

from replicate.figures import ablation_grid, ablation_report, rlfd  # noqa: E402
from replicate.figures import plots as figures  # noqa: E402
from replicate.figures.plots import (  # noqa: E402
    ALGO_COLORS,
    CurveBand,
    aggregate_png,
    algo_color,
    learning_curves_png,
    paired_curves_png,
    png_panels,
    seed_note,
)


@pytest.fixture
def drawn(monkeypatch):
    """The figures the drawing functions hand to ``png_bytes``, laid out, not closed."""
    kept = []

    def keep(fig):
        fig.draw_without_rendering()
        kept.append(fig)
        return b""

    monkeypatch.setattr(figures, "png_bytes", keep)
    yield kept
    for fig in kept:
        plt.close(fig)


def legends(fig):
    return list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend()]


def legend_colors(fig) -> dict[str, str]:
    """Each legend entry's label and its colour."""
    colors = {}
    for legend in legends(fig):
        for handle, text in zip(legend.legend_handles, legend.get_texts(), strict=True):
            color = handle.get_color() if hasattr(handle, "get_color") else handle.get_facecolor()
            colors[text.get_text()] = mcolors.to_hex(color)
    return colors


def bands(algos, envs, seeds=3):
    rng = np.random.default_rng(0)
    steps = np.arange(0, 50_001, 5000)
    out = []
    for env_id in envs:
        for algo in algos:
            per_seed = rng.normal(size=(seeds, len(steps))).cumsum(axis=1)
            mean = per_seed.mean(axis=0)
            out.append(
                CurveBand(
                    algo,
                    env_id,
                    steps,
                    mean,
                    mean - 1,
                    mean + 1,
                    seeds,
                    per_seed,
                    list(range(seeds)),
                )
            )
    return out


def assert_legend_outside_the_curves(fig):
    """One legend, and no panel that plots data carries it."""
    assert len(legends(fig)) == 1
    assert not any(ax.get_legend() for ax in fig.axes if ax.axison)


def test_an_algorithm_has_one_colour_in_every_figure(drawn):
    learning_curves_png(bands(["drl-eg", "sac", "ppo"], ["A-v0", "B-v0", "C-v0"]), {}, "Fig. 3")
    learning_curves_png(bands(["sac", "ddpgfd", "drl-eg", "drl-eg-gmm"], ["A-v0"]), {}, "other")
    steps = np.arange(5.0)
    paired_curves_png(
        [(s, {"sac": (steps, steps), "drl-eg": (steps, -steps)}) for s in range(4)], "Fig. 4"
    )
    taus = np.linspace(0, 1, 5)
    profile = (taus, taus, taus)
    aggregate_png(
        {"ppo": (0.5, 0.4, 0.6), "drl-eg": (0.7, 0.6, 0.8)},
        taus,
        {"ppo": profile, "drl-eg": profile},
    )
    rlfd._figure(
        {
            "iqm": {a: [0.5, 0.4, 0.6] for a in ("ibrl", "sac", "drl-eg", "rlpd")},
            "taus": taus,
            "profiles": {a: profile for a in ("ibrl", "sac", "drl-eg", "rlpd")},
            "efficiency": {
                a: (rlfd.CURVE_FRACTIONS,) * 3 for a in ("ibrl", "sac", "drl-eg", "rlpd")
            },
        }
    )
    seen = 0
    algo_rgbs = {mcolors.to_rgb(c) for c in ALGO_COLORS.values()}
    for fig in drawn:
        for label, color in legend_colors(fig).items():
            if label in ALGO_COLORS:
                seen += 1
                assert color == ALGO_COLORS[label], (label, fig)
        for ax in fig.axes:  # the curves themselves: each in an algorithm's colour or grey
            for line in ax.get_lines():
                rgb = mcolors.to_rgb(line.get_color())
                assert rgb in algo_rgbs or len(set(rgb)) == 1  # grey: references, styles
    assert seen == 3 + 4 + 2 + 2 + 4
    assert algo_color("some-new-algo") == algo_color("some-new-algo")
    assert len(set(ALGO_COLORS.values())) == len(ALGO_COLORS)


def test_fig3_is_a_grid_with_one_legend_outside_the_curves_and_a_line_per_seed(drawn):
    envs = ["A-v0", "B-v0", "C-v0", "D-v0", "E-v0"]
    learning_curves_png(bands(["sac", "drl-eg"], envs, seeds=4), {"A-v0": 1.0}, "Fig. 3")
    fig = drawn[0]
    panels = [ax for ax in fig.axes if ax.axison]
    assert len(panels) == 5
    assert len({round(ax.get_position().x0, 3) for ax in panels}) == figures.FIG3_COLUMNS
    assert_legend_outside_the_curves(fig)
    # the legend sits in the grid's free cell; each panel: 2 means + 2 x 4 seeds (+ demos)
    assert [len(ax.get_lines()) for ax in panels] == [11, 10, 10, 10, 10]
    assert {"mean over seeds", "one seed", "demonstrations' mean return"} <= set(legend_colors(fig))
    assert panels[0].get_title().endswith("4 seeds each")
    assert panels[0].xaxis.get_major_formatter()(1_000_000, 0) == "1M"
    # an even count: the legend goes below the panels
    learning_curves_png(bands(["sac"], envs[:4]), {}, "Fig. 3")
    assert_legend_outside_the_curves(drawn[1]) and drawn[1].legends


def test_fig4_is_a_grid_of_seeds_with_one_legend(drawn):
    steps = np.arange(5.0)
    paired_curves_png(
        [(s, {"sac": (steps, steps, steps), "drl-eg": (steps, -steps, steps)}) for s in range(4)],
        "Fig. 4",
    )
    fig = drawn[0]
    panels = [ax for ax in fig.axes if ax.axison]
    assert len({round(ax.get_position().x0, 3) for ax in panels}) == 2 and len(panels) == 4
    assert_legend_outside_the_curves(fig)
    assert {"training episodes", "deterministic evaluation"} <= set(legend_colors(fig))


def test_figures_are_saved_at_twice_the_displayed_density_with_their_panels_recorded():
    png = learning_curves_png(bands(["sac"], ["A-v0", "B-v0", "C-v0"]), {}, "Fig. 3")
    width = int.from_bytes(png[16:20], "big")  # the PNG header's width
    assert width == 2 * figures.FIGURE_WIDTH_IN * figures.DISPLAY_PX_PER_IN
    boxes = png_panels(png)
    assert len(boxes) == 3
    # at the content column's 1100 px each panel's plotting area is over 400 px wide
    assert min(w for _, _, w, _ in boxes) * figures.FIGURE_WIDTH_IN * 100 > 400


def test_seed_note_names_the_usual_count_and_the_exceptions():
    assert seed_note({"sac": 5, "ppo": 5}) == "5 seeds each"
    assert seed_note({"sac": 1}) == "1 seed"
    assert seed_note({"sac": 3, "ppo": 5, "ppo-bc": 5, "drl-eg": 3, "ddpgfd": 3}) == (
        "3 seeds; ppo, ppo-bc: 5"
    )


def test_summarise_keeps_each_seeds_curve_under_the_band():
    from replicate.figures.fig3 import summarise

    def run(seed, returns):
        curve = pd.DataFrame({"step": [0, 100, 200], "return_mean": returns})
        return types.SimpleNamespace(
            spec={"env_id": "A-v0", "algo": "drl-eg-gmm", "seed": seed}, curve=curve
        )

    bimodal = [
        run(0, [0, -50, -86]),
        run(1, [0, 40, 93]),
        run(2, [0, -60, -97]),
        run(3, [0, 20, 49]),
    ]
    (band,), _ = summarise(bimodal)
    assert band.seeds == [0, 1, 2, 3]
    assert band.per_seed[:, -1].tolist() == [-86, 93, -97, 49]
    assert band.mean[-1] == pytest.approx(np.mean([-86, 93, -97, 49]))


def test_the_ablation_t2_ticks_do_not_overlap(drawn):
    labels = [ablation_grid.threshold_label(t, 0.651) for t in (0, 0.651, 2.6, 10.4, 41.7)] + [
        "always"
    ]
    est = {"mean": 1.0, "low": 0.5, "high": 1.5, "n": 3}
    rows = [{"sigma": 0.1, "label": label, "final": est, "auc": est} for label in labels]
    ablation_report._figure(rows, 0.8, 0.7)
    fig = drawn[0]
    renderer = fig.canvas.get_renderer()
    for ax in (a for a in fig.axes if a.axison):
        boxes = [t.get_window_extent(renderer) for t in ax.get_xticklabels()]
        assert len(boxes) == len(labels)
        for left, right in zip(boxes, boxes[1:]):
            assert left.x1 < right.x0, "neighbouring T2 tick labels overlap"
    assert_legend_outside_the_curves(fig)
    assert legend_colors(fig)["SAC (mean over seeds)"] == ALGO_COLORS["sac"]


def test_published_sac_is_drawn_in_two_groups():
    """The same algorithm as ours (V-network SAC) and modern twin-Q SAC get markers and
    legend entries of their own."""

    from replicate.figures import plots as figures

    labels = []
    real = figures.shared_legend

    def record(fig, handles, names, *args, **kwargs):
        labels.extend(names)
        return real(fig, handles, names, *args, **kwargs)

    points = {"A-v0": [(100, 10.0, float("nan"), "V-network SAC"), (100, 20.0, 2.0, "twin-Q SAC")]}
    figures.shared_legend = record
    try:
        learning_curves_png(bands(["sac"], ["A-v0"]), {}, "Fig. 3", points)
    finally:
        figures.shared_legend = real
    assert [label for label in labels if label.startswith("published")] == [
        figures.PUBLISHED_LABELS["V-network SAC"],
        figures.PUBLISHED_LABELS["twin-Q SAC"],
    ]
