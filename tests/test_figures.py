"""Figure helpers: short env-step tick labels and the paper's panel order."""

import matplotlib.pyplot as plt

from replicate.figures import format_steps_axis, panel_order, steps_label
from replicate.profiles import get_profile


def test_steps_label_shortens_thousands_and_millions():
    assert [steps_label(v) for v in (0, 500, 2500, 50_000, 200_000, 1_000_000, 1_500_000)] == [
        "0", "500", "2.5k", "50k", "200k", "1M", "1.5M"]
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
        "MountainCarContinuous-v0", "Hopper-v5", "Ant-v5", "Other-v0"]
    assert panel_order(bands_envs, []) == ["Ant-v5", "Hopper-v5", "Other-v0",
                                          "MountainCarContinuous-v0"]
