import json

from replicate.cli import main


def test_fig4_pairs_seeds_with_identical_starts(smoke_fig3, tmp_path, capsys):
    store, _ = smoke_fig3  # the smoke Fig. 3 already holds these very runs
    out = tmp_path / "fig4"
    assert main(["fig4", "--profile", "smoke", "--env", "MountainCarContinuous-v0",
                 "--seeds", "2", "--store", str(store), "--out", str(out)]) == 0
    assert "training 0 runs" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert [r["seed"] for r in summary["rows"]] == [0, 1]
    assert all(r["same_start"] for r in summary["rows"])  # same seed, same initial weights
    assert summary["paired"] is not None and summary["claim"] is None  # claim 5 is about Ant
    html = (out / "index.html").read_text()
    assert "data:image/png;base64," in html and 'id="smoke-warning"' in html


def test_fig4_without_demonstrations_says_how_to_make_them(tmp_path, capsys, monkeypatch):
    from replicate import demos

    monkeypatch.setattr(demos, "default_demo_path", lambda env_id: tmp_path / "missing.npz")
    code = main(["fig4", "--profile", "smoke", "--env", "HalfCheetah-v5",
                 "--store", str(tmp_path), "--out", str(tmp_path / "out")])
    assert code == 2
    assert "nox -s experts -- --env HalfCheetah-v5" in capsys.readouterr().err


def test_reduced_mujoco_drl_eg_runs_wait_for_the_t2_rule(tmp_path, capsys):
    from replicate.experiments import (MUJOCO_T2_RULE, figure3_grid, get_profile,
                                       waits_for_t2_rule)

    assert MUJOCO_T2_RULE is None  # until the reduced ablation fixes it (README)
    assert main(["fig4", "--profile", "reduced", "--store", str(tmp_path / "runs")]) == 2
    assert "waits for the MuJoCo T2 rule" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()  # nothing trained, nothing written
    specs, _ = figure3_grid(get_profile("reduced"))
    waiting = {(s.env_id, s.algo) for s in specs if waits_for_t2_rule("reduced", s.env_id,
                                                                      s.algo)}
    assert waiting == {(env, "drl-eg") for env in ("Hopper-v5", "Walker2d-v5",
                                                   "HalfCheetah-v5", "Ant-v5")}
    assert not waits_for_t2_rule("quick", "Ant-v5", "drl-eg")  # quick keeps the spacing rule


def test_a_fixed_t2_rule_gives_the_ablation_runs_of_its_setting(monkeypatch):
    from replicate import ablation, experiments
    from replicate.experiments import figure3_grid, figure4_grid, get_profile
    from replicate.runner import prepare

    reduced = get_profile("reduced")
    spacing = ablation.threshold_spacing("Ant-v5")

    def ant_drl_eg(specs, algo="drl-eg"):
        return [s for s in specs if s.env_id == "Ant-v5" and s.algo == algo]

    gmm_before = ant_drl_eg(figure3_grid(reduced)[0], "drl-eg-gmm")
    monkeypatch.setattr(experiments, "MUJOCO_T2_RULE", 16)
    ruled = ant_drl_eg(figure3_grid(reduced)[0])
    # a ruled Fig. 3 run is the ablation's run of that setting: same spec, so same run id
    sweep = ablation.ablation_specs(reduced, "Ant-v5", 16 * spacing, 0.1, 3)
    assert [prepare(s).run_id for s in ruled[:3]] == [prepare(s).run_id for s in sweep]
    assert all(s.hyperparameters["guide_threshold"] == 16 * spacing
               for s in ant_drl_eg(figure4_grid(reduced)))
    assert ant_drl_eg(figure3_grid(reduced)[0], "drl-eg-gmm") == gmm_before  # T2 unused there
    assert experiments.drl_eg_env_defaults("Ant-v5", "quick")["guide_threshold"] == spacing
    assert not experiments.waits_for_t2_rule("reduced", "Ant-v5", "drl-eg")
    monkeypatch.setattr(experiments, "MUJOCO_T2_RULE", "always")
    assert {s.hyperparameters["guide_threshold"]
            for s in ant_drl_eg(figure3_grid(reduced)[0])} == {ablation.ALWAYS}
