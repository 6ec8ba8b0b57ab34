"""The SAC authors' random start as a setting of the SAC family: off by default and then out
of a run's address (every committed run still resolves to its directory), and when on, the
first steps' actions are the seed's own uniform draws, in one run and in a seed batch."""

import json
from pathlib import Path

import numpy as np
import pytest

from baselines.common.random_start import random_start_action
from replicate.store.runner import prepare
from replicate.store.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY, batch_curves, train_tiny

ROOT = Path(__file__).resolve().parents[1]


def _committed_by_algo() -> list[Path]:
    """One committed run of each algorithm and env (resolving loads its demonstrations)."""
    seen, runs = set(), []
    for spec_file in sorted((ROOT / "runs").glob("[!.]*/spec.json")):
        algo, env = spec_file.parent.name.split("__")[:2]
        if (algo, env) not in seen:
            seen.add((algo, env))
            runs.append(spec_file.parent)
    return runs


@pytest.mark.parametrize("run_dir", _committed_by_algo(), ids=lambda p: p.name)
def test_committed_runs_keep_their_addresses(run_dir):
    resolved = json.loads((run_dir / "spec.json").read_text())
    # the default start (0) is never recorded; the study's random-start runs record theirs
    assert resolved["hyperparameters"].get("random_start_steps", 10_000) > 0
    spec = RunSpec(
        resolved["algo"],
        resolved["env_id"],
        resolved["seed"],
        resolved["total_steps"],
        resolved["eval_interval"],
        resolved["eval_episodes"],
        resolved["hyperparameters"],
        resolved.get("demos_path"),
    )
    assert prepare(spec).run_id == run_dir.name


def test_a_random_start_changes_the_address_and_is_recorded():
    plain = prepare(RunSpec("sac", MOUNTAINCAR, 0, 400, 200, 1, dict(TINY)))
    random = prepare(
        RunSpec("sac", MOUNTAINCAR, 0, 400, 200, 1, dict(TINY, random_start_steps=150))
    )
    assert plain.run_id != random.run_id
    assert random.resolved["hyperparameters"]["random_start_steps"] == 150


def test_one_run_takes_its_seeds_uniform_actions_first():
    _, replay = train_tiny("sac", seed=3, steps=300, random_start_steps=150)
    buffer = replay.member(0)
    low, high = np.array([-1.0]), np.array([1.0])
    expected = np.stack([random_start_action(3, step, low, high) for step in range(1, 151)])
    np.testing.assert_array_equal(buffer.actions[:150], expected)
    assert not np.array_equal(
        buffer.actions[150:300],
        np.stack([random_start_action(3, step, low, high) for step in range(151, 301)]),
    )


def test_a_seed_batch_member_draws_its_seeds_random_start(tmp_path, monkeypatch):
    """Each member's first actions are the draws its run alone would take (the same
    function of its own seed and the step), and the policy acts from the step after."""
    import baselines.training_loop as training_loop
    from baselines.registry import get_algorithm

    drawn = []

    def recording(seed, step, low, high):
        drawn.append((seed, step))
        return random_start_action(seed, step, low, high)

    monkeypatch.setattr(training_loop, "random_start_action", recording)
    config = get_algorithm("sac").make_config(dict(TINY, random_start_steps=150))
    batch_curves("sac", config, tmp_path / "batch", seeds=(0, 1), steps=400)
    assert drawn == [(seed, step) for step in range(1, 151) for seed in (0, 1)]


def test_the_study_reuses_fig3s_sac_runs_for_the_default_start():
    from replicate.figures.fig3 import figure3_grid
    from replicate.figures.random_start import random_start_grid
    from replicate.grids.profiles import get_profile

    fig3 = {prepare(s).run_id for s in figure3_grid(get_profile("reduced"))[0] if s.algo == "sac"}
    study = [prepare(s) for s in random_start_grid("reduced")]
    default = {p.run_id for p in study if not p.spec.hyperparameters["random_start_steps"]}
    assert len(default) == 6 and default <= fig3
    assert {p.resolved["hyperparameters"].get("random_start_steps") for p in study} == {
        None,
        10_000,
    }


def test_envs_limits_what_the_study_trains(capsys, tmp_path):
    from replicate.cli.main import main

    args = ["random-start", "--profile", "reduced", "--store", str(tmp_path), "--dry-run"]
    assert main([*args, "--workers", "1"]) == 0
    everything = capsys.readouterr().out
    assert "HalfCheetah-v5" in everything and "Ant-v5" in everything
    assert main([*args, "--workers", "1", "--envs", "HalfCheetah-v5"]) == 0
    planned = capsys.readouterr().out
    assert "HalfCheetah-v5" in planned and "Ant-v5" not in planned


@pytest.mark.slow
def test_the_study_trains_the_random_starts_and_pairs_them_by_seed(tmp_path):
    from replicate.cli.main import main

    store, out = tmp_path / "runs", tmp_path / "report"
    assert (
        main(
            [
                "random-start",
                "--profile",
                "smoke",
                "--store",
                str(store),
                "--out",
                str(out),
                "--workers",
                "1",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    (row,) = summary["rows"]
    assert row["env_id"] == MOUNTAINCAR and row["random_start_steps"] == [400]
    assert row["final"]["method"] == "95% paired t-interval, 3 pairs"
    assert len(summary["run_ids"]) == 6 and (out / "index.html").is_file()
    recorded = {  # the runs listed as the random start's are those that record one
        run: "random_start_steps" in (store / run / "spec.json").read_text() for run in row["runs"]
    }
    assert sorted(r for r, has in recorded.items() if has) == row["random_start_runs"]
    assert len(row["random_start_runs"]) == 3
    from replicate.figures.random_start import stored_rows

    (stored,) = stored_rows("smoke", store)  # what the Fig. 3 threats line reads
    assert stored["runs"] == row["runs"] and stored["final"]["value"] == row["final"]["value"]


def _row(env_id: str, value: float, low: float, high: float, n: int = 3) -> dict:
    method = f"95% paired t-interval, {n} pairs"
    final = {"value": value, "low": low, "high": high, "n": n, "method": method}
    return {"env_id": env_id, "steps": 200_000, "final": final}


def test_the_threats_line_says_what_the_study_measured():
    from replicate.figures.random_start import command, start_threat

    unmeasured = start_threat("reduced", [])
    assert "initial policy" in unmeasured and command("reduced") in unmeasured
    partial = start_threat("reduced", [_row("HalfCheetah-v5", 812.3, -100.2, 1700.9)])
    assert (
        "HalfCheetah-v5 at 200,000 steps: +812 [-100, 1701], 95% paired t-interval, 3 pairs, "
        "the interval includes 0" in partial
    )
    assert "Ant-v5 not measured yet" in partial
    both = start_threat(
        "reduced",
        [_row("HalfCheetah-v5", 900.0, 100.0, 1700.0), _row("Ant-v5", -300.0, -500.0, -100.0)],
    )
    assert "random start higher" in both and "[-500, -100]" in both
    assert both.endswith("random start lower.")
    one = start_threat("reduced", [_row("Ant-v5", 512.0, float("nan"), float("nan"), n=1)])
    assert "+512 from 1 pair (no interval)" in one and "nan" not in one
    assert start_threat("quick", []) is None  # no MuJoCo env of the study at that profile


def test_the_fig3_threats_end_with_the_start_line():
    from replicate.reports.pages import threats_to_validity
    from replicate.store.runs import load_run

    ant = next(p for p in sorted((ROOT / "runs").glob("sac__Ant-v5__*")) if p.is_dir())
    threats = threats_to_validity([load_run(ant)], [], sac_start="how SAC starts")
    assert threats[-1] == "how SAC starts"
    assert "how SAC starts" not in threats_to_validity([load_run(ant)], [])
