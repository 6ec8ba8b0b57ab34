import json

from replicate.cli.main import main


def test_fig4_pairs_seeds_with_identical_starts(smoke_fig3, tmp_path, capsys):
    store, _ = smoke_fig3  # the smoke Fig. 3 already holds these very runs
    out = tmp_path / "fig4"
    assert (
        main(
            [
                "fig4",
                "--profile",
                "smoke",
                "--env",
                "MountainCarContinuous-v0",
                "--seeds",
                "2",
                "--store",
                str(store),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert "training 0 runs" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert [r["seed"] for r in summary["rows"]] == [0, 1]
    assert all(r["same_start"] for r in summary["rows"])  # same seed, same initial weights
    shares = [r["guided_share"] for r in summary["rows"]]  # T2 0.05 admits most states
    assert all(0 <= share <= 1 for share in shares) and max(shares) > 0
    assert summary["paired"] is not None and summary["claim"] is None  # claim 5 is about Ant
    html = (out / "index.html").read_text()
    assert "data:image/png;base64," in html and 'id="smoke-warning"' in html
    assert 'id="guidance"' in html and summary["guidance"][0]["t2"] == [0.05]
    # two of the paper's four pairs: the report says which seeds it lacks and how to train them
    missing = {(m["algo"], m["reason"]) for m in summary["missing"]}
    assert {algo for algo, _ in missing} == {"sac", "drl-eg"}
    assert all(
        why.startswith("seeds 2, 3 not in the store yet") and "replicate-fig4" in why
        for _, why in missing
    )
    assert 'id="incomplete"' in html and "Incomplete: 2 paired" in html
    assert summary["paired"]["method"] == "95% paired t-interval, 2 pairs"
    assert "paired t-test" in summary["paired"]["test"] and summary["paired"]["test"] in html


def test_fig4_dry_run_plans_the_paired_batches_and_writes_nothing(tmp_path, capsys):
    store, out = tmp_path / "runs", tmp_path / "fig4"
    assert (
        main(
            [
                "fig4",
                "--profile",
                "smoke",
                "--env",
                "MountainCarContinuous-v0",
                "--seeds",
                "3",
                "--batch",
                "3",
                "--store",
                str(store),
                "--out",
                str(out),
                "--dry-run",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "dry run: 6 runs, 0 already in" in printed
    assert "6 runs in 2 seed batches" in printed and "seeds 0,1,2" in printed
    assert not store.exists() and not out.exists()


def test_fig4_without_demonstrations_says_how_to_make_them(tmp_path, capsys, monkeypatch):
    from replicate import demos

    monkeypatch.setattr(demos, "default_demo_path", lambda env_id: tmp_path / "missing.npz")
    code = main(
        [
            "fig4",
            "--profile",
            "smoke",
            "--env",
            "HalfCheetah-v5",
            "--store",
            str(tmp_path),
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert code == 2
    assert "nox -s experts -- --env HalfCheetah-v5" in capsys.readouterr().err


def test_reduced_mujoco_drl_eg_runs_waited_for_the_t2_rule(monkeypatch, tmp_path, capsys):
    from replicate.figures.fig3 import figure3_grid
    from replicate.grids import drl_eg_settings
    from replicate.grids.drl_eg_settings import waits_for_t2_rule
    from replicate.grids.profiles import get_profile

    assert drl_eg_settings.MUJOCO_T2_RULE in drl_eg_settings.T2_RULE_SETTINGS  # fixed
    specs, _ = figure3_grid(get_profile("reduced"))
    assert not [s for s in specs if waits_for_t2_rule("reduced", s.env_id, s.algo)]
    # before the ablation fixed it, the ruled cells waited and a figure refused to train them
    monkeypatch.setattr(drl_eg_settings, "MUJOCO_T2_RULE", None)
    assert main(["fig4", "--profile", "reduced", "--store", str(tmp_path / "runs")]) == 2
    assert "waits for the MuJoCo T2 rule" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()  # nothing trained, nothing written
    specs, _ = figure3_grid(get_profile("reduced"))
    waiting = {(s.env_id, s.algo) for s in specs if waits_for_t2_rule("reduced", s.env_id, s.algo)}
    assert waiting == {
        (env, "drl-eg") for env in ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")
    }
    assert not waits_for_t2_rule("quick", "Ant-v5", "drl-eg")  # quick keeps the spacing rule


def test_a_fixed_t2_rule_gives_the_ablation_runs_of_its_setting(monkeypatch):
    import pytest

    from replicate.errors import HarnessError
    from replicate.figures import ablation_grid
    from replicate.figures.fig3 import figure3_grid
    from replicate.figures.fig4 import figure4_grid
    from replicate.figures.rlfd import rlfd_grid
    from replicate.grids import drl_eg_settings
    from replicate.grids.profiles import get_profile
    from replicate.store.runner import prepare

    reduced = get_profile("reduced")
    grid = ablation_grid.default_thresholds("reduced", "Ant-v5")  # 1x, 4x, 16x, 64x, always

    def ant(specs, algo="drl-eg"):
        return [s for s in specs if s.env_id == "Ant-v5" and s.algo == algo]

    def ids(specs):
        return [prepare(s).run_id for s in specs]

    gmm_before = ant(figure3_grid(reduced)[0], "drl-eg-gmm")
    for setting, threshold in zip(drl_eg_settings.T2_RULE_SETTINGS, grid):
        monkeypatch.setattr(drl_eg_settings, "MUJOCO_T2_RULE", setting)
        sweep = ablation_grid.ablation_specs(reduced, "Ant-v5", threshold, 0.1, 3)
        # a ruled run is the ablation's run of that setting: same spec, same run id
        assert ids(ant(figure3_grid(reduced)[0])[:3]) == ids(sweep)
        assert ids(ant(rlfd_grid(reduced)[0])[:3]) == ids(sweep)
        assert {s.hyperparameters["guide_threshold"] for s in ant(figure4_grid(reduced))} == {
            threshold
        }
    assert ant(figure3_grid(reduced)[0], "drl-eg-gmm") == gmm_before  # its T2 is unused
    assert drl_eg_settings.drl_eg_env_defaults("Ant-v5", "quick")["guide_threshold"] == grid[0]
    assert not drl_eg_settings.waits_for_t2_rule("reduced", "Ant-v5", "drl-eg")
    monkeypatch.setattr(drl_eg_settings, "MUJOCO_T2_RULE", "2x")  # not a setting of the sweep
    with pytest.raises(HarnessError, match="not a setting of the ablation"):
        figure3_grid(reduced)


def test_reports_name_where_each_t2_comes_from(monkeypatch):
    from types import SimpleNamespace

    from replicate.figures.fig3 import figure3_grid
    from replicate.grids import drl_eg_settings
    from replicate.grids.drl_eg_settings import guidance_settings
    from replicate.grids.profiles import get_profile

    monkeypatch.setattr(drl_eg_settings, "MUJOCO_T2_RULE", None)  # before the rule, then with it
    specs = [s for s in figure3_grid(get_profile("reduced"))[0] if s.env_id == "Ant-v5"]
    rows = {g["algo"]: g for g in guidance_settings("reduced", [], specs)}
    assert set(rows) == {"drl-eg", "drl-eg-gmm"} and rows["drl-eg"]["t2"] == []
    assert rows["drl-eg"]["source"].startswith("none yet: waits for the MuJoCo T2 rule")
    assert rows["drl-eg-gmm"]["source"].startswith("unused")
    monkeypatch.setattr(drl_eg_settings, "MUJOCO_T2_RULE", "16x")
    run = SimpleNamespace(
        spec={
            "algo": "drl-eg",
            "env_id": "Ant-v5",
            "seed": 0,
            "hyperparameters": {"guide_threshold": 36.3, "guide_noise_std": 0.1},
        },
        guided_share=0.25,
    )
    rows = {g["algo"]: g for g in guidance_settings("reduced", [run], specs)}
    assert rows["drl-eg"]["t2"] == [36.3] and rows["drl-eg"]["sigma"] == [0.1]
    assert rows["drl-eg"]["guided_share"] == [0.25]
    assert rows["drl-eg"]["runs"] == 1 and rows["drl-eg-gmm"]["runs"] == 0
    assert not rows["drl-eg"]["never_guided"] and not rows["drl-eg-gmm"]["never_guided"]
    run.guided_share = 0.0  # a T2 below every distance the runs met: flagged, not 0.0%
    rows = {g["algo"]: g for g in guidance_settings("reduced", [run], specs)}
    assert rows["drl-eg"]["never_guided"] and not rows["drl-eg-gmm"]["never_guided"]
    assert "rule 16x (16 times the median spacing" in rows["drl-eg"]["source"]
    quick = guidance_settings("quick", [run])
    assert quick[0]["source"].endswith("(the spacing rule, 1x)")
    run.spec["hyperparameters"]["guide_threshold"] = drl_eg_settings.ALWAYS_GUIDE
    assert guidance_settings("quick", [run])[0]["t2_labels"] == ["always"]


def test_guided_share_weighs_each_points_fraction_by_the_steps_it_covers(tmp_path):
    import math

    import pandas as pd

    from replicate.store.runner import Run

    curve = pd.DataFrame({"step": [0, 100, 200, 250], "guided_fraction": [math.nan, 0.5, 0.0, 1.0]})
    assert Run(tmp_path, {}, curve, {}).guided_share == (50 + 0 + 50) / 250
    ppo = curve.assign(guided_fraction=math.nan)  # an algorithm without a guider
    assert math.isnan(Run(tmp_path, {}, ppo, {}).guided_share)


def test_an_ant_fig4_below_the_papers_budget_says_what_it_can_show(tmp_path):
    import numpy as np
    import pandas as pd

    from replicate.figures.fig4 import write_figure4_report
    from replicate.grids.profiles import GridOutcome, get_profile
    from replicate.store.runner import Run

    def run(algo: str, seed: int, end: float) -> Run:
        curve = pd.DataFrame(
            {
                "step": [0, 250_000, 500_000],
                "return_mean": [0.0, end / 2, end],
                "returns": ["[0.0]"] * 3,
                "guided_fraction": [np.nan, 0.1, 0.1],
                "train_return": [np.nan] * 3,
            }
        )
        spec = {"env_id": "Ant-v5", "algo": algo, "seed": seed, "total_steps": 500_000}
        return Run(tmp_path / f"{algo}-{seed}", spec, curve, {"git_revision": "abc"})

    runs = [
        run(algo, seed, end + seed)
        for seed in range(4)
        for algo, end in (("sac", 900.0), ("drl-eg", 1200.0))
    ]
    out = tmp_path / "fig4"
    write_figure4_report(GridOutcome(runs, [], None), get_profile("reduced"), "Ant-v5", out)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["claim"]["budget_note"].startswith("At 500,000 steps")
    html = (out / "index.html").read_text()
    assert "What this budget can show" in html and "Profile <strong>reduced</strong>" in html
