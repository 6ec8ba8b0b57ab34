"""The run store answers by cell: a cell's runs differ only in seed, and grouping runs of
several settings as one cell fails in one line (the committed Ant runs hold Fig. 3's DRL-EG
cell beside the threshold ablation's T2 points, at three budgets)."""

from pathlib import Path

import pytest

from replicate.claims.groups import group_runs
from replicate.errors import HarnessError
from replicate.store import query
from replicate.store.runs import completed_runs

STORE = Path(__file__).resolve().parents[1] / "runs"
ANT_T2 = 2.921  # the MuJoCo T2 rule's point on Ant (the committed ablation's choice)


def spec(seed: int, t2: float = 0.5, steps: int = 1000) -> dict:
    return {
        "algo": "drl-eg",
        "env_id": "Ant-v5",
        "seed": seed,
        "total_steps": steps,
        "eval_interval": 100,
        "hyperparameters": {"guide_threshold": t2},
    }


def test_a_cell_matches_its_fields_settings_and_seed_range():
    cell = query.Cell("drl-eg", "Ant-v5", 1000, settings={"guide_threshold": 0.5}, seeds=(0, 3))
    assert cell.matches(spec(2))
    assert not cell.matches(spec(3))  # the range is half-open
    assert not cell.matches(spec(0, t2=1.0))
    assert not cell.matches(spec(0, steps=2000))
    assert query.Cell().matches(spec(7))  # nothing asked, anything matches
    assert query.cell_key(spec(0)) == query.cell_key(spec(9)) != query.cell_key(spec(0, t2=1))


@pytest.fixture(scope="module")
def ant_drl_eg():
    runs = completed_runs(STORE)
    return [r for r in runs if r.spec["algo"] == "drl-eg" and r.spec["env_id"] == "Ant-v5"]


def test_the_committed_ant_runs_are_several_cells_and_grouping_them_as_one_fails(ant_drl_eg):
    grouped = query.cells(ant_drl_eg)
    assert len(grouped) > 3  # T2 points and budgets, each a cell
    assert all(
        len({r.spec["seed"] for r in members}) == len(members) for members in grouped.values()
    )
    with pytest.raises(HarnessError, match="different settings would be judged as seeds"):
        group_runs(ant_drl_eg)


def test_one_cell_from_the_store_holds_one_setting_over_its_seeds(ant_drl_eg):
    steps = 200_000
    cell = query.Cell("drl-eg", "Ant-v5", steps, settings={"guide_threshold": ANT_T2})
    found = query.select(ant_drl_eg, cell)
    assert found and len(query.cells(found)) == 1
    assert [r.spec["seed"] for r in found] == sorted(r.spec["seed"] for r in found)
    expected = [
        r
        for r in ant_drl_eg
        if r.spec["total_steps"] == steps and r.spec["hyperparameters"]["guide_threshold"] == ANT_T2
    ]
    assert {r.path for r in found} == {r.path for r in expected}
    assert set(group_runs(found)) == {("Ant-v5", "drl-eg")}
