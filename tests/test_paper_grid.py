"""The paper profile's Fig. 3 grid is whole: every algorithm on every env of the paper, each
able to train on the committed demonstrations of a MuJoCo env."""

import math

import pytest

from envs import PAPER_ENV_IDS
from replicate.figures.fig3 import FIG3_ALGORITHMS, figure3_grid
from replicate.grids.drl_eg_settings import drl_eg_env_defaults
from replicate.grids.profiles import get_profile
from replicate.grids.train import algorithm_overrides
from tests.helpers import train_tiny


def test_paper_grid_has_all_six_algorithms_on_all_five_envs():
    specs, skipped = figure3_grid(get_profile("paper"), seeds=1)
    assert skipped == []  # every env has committed demonstrations
    cells = {(s.algo, s.env_id) for s in specs}
    assert cells == {(a, e) for a in FIG3_ALGORITHMS for e in PAPER_ENV_IDS}


@pytest.mark.parametrize("algo", FIG3_ALGORITHMS)
def test_each_algorithm_trains_on_hopper_with_its_demonstrations(algo):
    overrides = algorithm_overrides(algo, get_profile("smoke").overrides)
    if algo.startswith("drl-eg"):
        overrides.update(drl_eg_env_defaults("Hopper-v5"))
    curve, _ = train_tiny(algo, seed=0, steps=400, env_id="Hopper-v5", **overrides)
    assert [p.step for p in curve] == [0, 200, 400]
    assert all(math.isfinite(r) for p in curve for r in p.returns)
