import hashlib
import json

import numpy as np
import optuna
import pandas as pd

from replicate.cli.main import main
from replicate.figures.ablation_grid import area_under_curve
from replicate.store.runner import Run


def test_area_under_curve_hand_computed(tmp_path):
    curve = pd.DataFrame({"step": [0, 100, 300], "return_mean": [0.0, 10.0, 10.0]})
    run = Run(tmp_path, {}, curve, {})
    # trapezoids: 100 * 5 + 200 * 10 = 2500 over 300 steps
    assert area_under_curve(run) == 2500 / 300


def test_smoke_sweep_checks_zero_threshold_against_sac_and_resumes(tmp_path, capsys):
    store, out = tmp_path / "runs", tmp_path / "report"
    args = [
        "ablate-threshold",
        "--profile",
        "smoke",
        "--seeds",
        "1",
        "--store",
        str(store),
        "--out",
        str(out),
        "--thresholds",
        "0",
        "1000000",
    ]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["zero_threshold_equals_sac"] == {"pairs": 1, "equal": 1, "holds": True}
    assert [r["label"] for r in summary["rows"]] == ["0 (off)", "always"]
    assert summary["rows"][0]["guided_share"] == [0.0]  # T2 = 0 never guides
    assert all(len(r["runs"]) == 1 and np.isfinite(r["final"]["mean"]) for r in summary["rows"])
    assert (store / "ablate-threshold.db").is_file()
    html = (out / "index.html").read_text()
    assert 'id="smoke-warning"' in html and "data:image/png;base64," in html

    capsys.readouterr()
    assert main(args) == 0  # the study and the store hold everything: nothing is trained
    assert "training" not in capsys.readouterr().err
    assert json.loads((out / "summary.json").read_text())["rows"] == summary["rows"]
    # rebuilt from the store alone, the report names the study the sweep trained in
    from replicate.figures.ablation import rebuild_threshold_ablation

    rebuilt = rebuild_threshold_ablation(
        "smoke", store, out_dir=tmp_path / "rebuilt", env_id="MountainCarContinuous-v0"
    )
    again = json.loads((rebuilt.parent / "summary.json").read_text())
    assert again["study_name"] == summary["study_name"]


def test_a_dry_run_lists_each_sweep_point_and_touches_nothing(tmp_path, capsys):
    store, out = tmp_path / "runs", tmp_path / "report"
    assert (
        main(
            [
                "ablate-threshold",
                "--profile",
                "smoke",
                "--seeds",
                "2",
                "--thresholds",
                "0",
                "0.05",
                "--sigmas",
                "0.1",
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
    points = [line for line in printed.splitlines() if " drl-eg " in line]
    assert len(points) == 2 and "guide_threshold=0.0)" in points[0]
    assert "guide_threshold=0.05)" in points[1]
    assert not store.exists() and not out.exists()  # not even the optuna database


def test_a_plan_tells_points_apart_whatever_order_their_runs_come_in(tmp_path, capsys):
    from replicate.grids.planning import print_plan
    from replicate.store.runner import prepare
    from replicate.store.spec import RunSpec

    default = prepare(RunSpec("drl-eg", "MountainCarContinuous-v0", 0, 400, 200, 1, {}))
    point = prepare(
        RunSpec("drl-eg", "MountainCarContinuous-v0", 1, 400, 200, 1, {"guide_threshold": 0.2})
    )
    for runs in ([default, point], [point, default]):
        print_plan(runs, runs, tmp_path, workers=1)
        lines = [line for line in capsys.readouterr().out.splitlines() if " drl-eg " in line]
        assert len(lines) == 2 and sorted(line[-5:] for line in lines) == ["=0.2)", "ault)"]


def test_with_batch_the_whole_sweep_trains_as_one_batch_and_t2_zero_still_equals_sac(tmp_path):
    from replicate.store.runner import load_run

    store, out = tmp_path / "runs", tmp_path / "report"
    assert (
        main(
            [
                "ablate-threshold",
                "--profile",
                "smoke",
                "--seeds",
                "2",
                "--store",
                str(store),
                "--out",
                str(out),
                "--thresholds",
                "0",
                "1000000",
                "--batch",
                "8",
                "--workers",
                "1",
                "--device",
                "cpu",
                "--checkpoint-interval",
                "0",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    drl_eg = [load_run(store / run) for row in summary["rows"] for run in row["runs"]]
    assert [r.provenance["batch"]["size"] for r in drl_eg] == [4] * 4  # both points, one batch
    # a member's curve does not depend on its neighbours: T2 = 0 is still SAC, seed by seed
    assert summary["zero_threshold_equals_sac"] == {"pairs": 2, "equal": 2, "holds": True}


def test_a_failed_grid_point_is_trained_when_the_sweep_runs_again(tmp_path):
    store, out = tmp_path / "runs", tmp_path / "report"
    store.mkdir()
    grid = {"guide_threshold": [0.0, 1000000.0], "guide_noise_std": [0.1]}
    grid_id = hashlib.sha256(
        json.dumps([grid["guide_threshold"], grid["guide_noise_std"]]).encode()
    ).hexdigest()[:8]
    study = optuna.create_study(
        study_name=f"ablate-threshold-smoke-MountainCarContinuous-v0-s1-{grid_id}",
        storage=f"sqlite:///{store / 'ablate-threshold.db'}",
        direction="maximize",
    )
    study.add_trial(
        optuna.trial.create_trial(  # an earlier call failed at T2 = always
            state=optuna.trial.TrialState.FAIL,
            params={"guide_threshold": 1000000.0, "guide_noise_std": 0.1},
            distributions={
                k: optuna.distributions.CategoricalDistribution(v) for k, v in grid.items()
            },
        )
    )
    args = [
        "ablate-threshold",
        "--profile",
        "smoke",
        "--seeds",
        "1",
        "--store",
        str(store),
        "--out",
        str(out),
        "--thresholds",
        "0",
        "1000000",
    ]
    assert main(args) == 0
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert [len(r["runs"]) for r in rows] == [1, 1]


def test_a_mujoco_sweep_takes_t2_in_multiples_of_the_spacing_and_shows_guidance(
    tmp_path, monkeypatch
):
    import dataclasses

    from replicate.figures import ablation, ablation_grid
    from replicate.grids import profiles

    env_id = "Walker2d-v5"
    smoke = profiles.PROFILES["smoke"]
    tiny = dataclasses.replace(
        smoke,
        steps={**smoke.steps, env_id: 200},
        eval_interval={**smoke.eval_interval, env_id: 100},
    )
    monkeypatch.setitem(profiles.PROFILES, "smoke", tiny)
    spacing = ablation_grid.threshold_spacing(env_id)
    assert spacing and ablation_grid.default_thresholds("smoke", env_id) == [
        spacing,
        4 * spacing,
        16 * spacing,
        64 * spacing,
        ablation_grid.ALWAYS,
    ]
    store, out = tmp_path / "runs", tmp_path / "report"
    assert (
        main(
            [
                "ablate-threshold",
                "--profile",
                "smoke",
                "--env",
                env_id,
                "--seeds",
                "1",
                "--store",
                str(store),
                "--out",
                str(out),
                "--workers",
                "1",
                "--device",
                "cpu",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["spacing"] == spacing
    assert [r["label"].split(" ")[0] for r in summary["rows"]] == [
        "1x",
        "4x",
        "16x",
        "64x",
        "always",
    ]
    shares = [r["admitted_random_share"] for r in summary["rows"]]  # random play's states
    assert shares == sorted(shares) and shares[-1] == 1.0 and shares[0] < 1.0
    html = (out / "index.html").read_text()
    assert 'id="curves"' in html and html.count("data:image/png;base64,") == 2
    # the guided share grows with T2; an untrained policy keeps the gate open, so always-guide
    # takes every training step after the first evaluation
    fractions = []
    for row in summary["rows"]:
        curve = pd.read_csv(store / row["runs"][0] / "curve.csv")
        fractions.append(float(curve["guided_fraction"].iloc[1:].mean()))
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and fractions[0] < 1.0
    shares = [row["guided_share"][0] for row in summary["rows"]]  # of the whole run
    assert shares == sorted(shares) and shares[-1] == 1.0 and shares[0] < 1.0
    # the rebuilt report (the `report` command's path) reads the same runs
    rebuilt = ablation.rebuild_threshold_ablation("smoke", store, tmp_path / "again", env_id)
    again = json.loads((rebuilt.parent / "summary.json").read_text())
    assert again["rows"] == summary["rows"]
    # the MuJoCo rule's standing: one seed of Walker2d only, so no choice yet
    rule = summary["t2_rule"]
    assert not rule["complete"] and rule["choice"] is None
    assert all(
        list(r["per_env"]) == [env_id] and r["per_env"][env_id]["n"] == 1 for r in rule["rows"]
    )
    assert 'id="t2-rule"' in html and "Not chosen yet" in html


def test_the_t2_rule_is_the_largest_mean_gain_and_only_once_every_cell_is_in():
    import numpy as np

    from replicate.figures.ablation import choose_t2_rule
    from replicate.grids.drl_eg_settings import T2_RULE_SETTINGS

    envs = ("Ant-v5", "Walker2d-v5")
    gains = {
        setting: {"Ant-v5": [0.1 * i] * 3, "Walker2d-v5": [0.0, 0.1, 0.2]}
        for i, setting in enumerate(T2_RULE_SETTINGS)
    }
    gains["16x"] = {"Ant-v5": [0.5, 0.6, 0.7], "Walker2d-v5": [0.3, 0.2, 0.1]}  # mean 0.4
    rng = np.random.default_rng(0)
    choice = choose_t2_rule(gains, rng, envs, seeds=3)
    assert choice["complete"] and choice["choice"] == "16x"
    row = next(r for r in choice["rows"] if r["setting"] == "16x")
    assert np.isclose(row["gain"], 0.4) and row["low"] <= 0.4 <= row["high"] and row["low"] > 0
    # an exact tie (values exact in binary): the smaller T2 wins, whichever comes first
    gains["4x"] = {"Ant-v5": [0.5] * 3, "Walker2d-v5": [0.5] * 3}
    gains["16x"] = {"Ant-v5": [0.75] * 3, "Walker2d-v5": [0.25] * 3}
    assert choose_t2_rule(gains, rng, envs, seeds=3)["choice"] == "4x"
    gains["4x"], gains["16x"] = gains["16x"], gains["4x"]
    assert choose_t2_rule(gains, rng, envs, seeds=3)["choice"] == "4x"
    gains["always"]["Walker2d-v5"] = [9.0, 9.0]  # a missing seed: no choice, only a leader
    partial = choose_t2_rule(gains, rng, envs, seeds=3)
    assert not partial["complete"] and partial["choice"] is None
    assert partial["leader"] == "always"
    del gains["64x"]["Ant-v5"]  # an env not trained: no mean gain for that setting
    row = next(r for r in choose_t2_rule(gains, rng, envs, 3)["rows"] if r["setting"] == "64x")
    assert np.isnan(row["gain"]) and list(row["per_env"]) == ["Walker2d-v5"]
