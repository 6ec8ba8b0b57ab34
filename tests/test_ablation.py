import hashlib
import json

import numpy as np
import optuna
import pandas as pd

from replicate.ablation import area_under_curve
from replicate.cli import main
from replicate.runner import Run


def test_area_under_curve_hand_computed(tmp_path):
    curve = pd.DataFrame({"step": [0, 100, 300], "return_mean": [0.0, 10.0, 10.0]})
    run = Run(tmp_path, {}, curve, {})
    # trapezoids: 100 * 5 + 200 * 10 = 2500 over 300 steps
    assert area_under_curve(run) == 2500 / 300


def test_smoke_sweep_checks_zero_threshold_against_sac_and_resumes(tmp_path, capsys):
    store, out = tmp_path / "runs", tmp_path / "report"
    args = ["ablate-threshold", "--profile", "smoke", "--seeds", "1", "--store", str(store),
            "--out", str(out), "--thresholds", "0", "1000000"]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["zero_threshold_equals_sac"] == {"pairs": 1, "equal": 1, "holds": True}
    assert [r["label"] for r in summary["rows"]] == ["0 (off)", "always"]
    assert all(len(r["runs"]) == 1 and np.isfinite(r["final"]["mean"]) for r in summary["rows"])
    assert (store / "ablate-threshold.db").is_file()
    html = (out / "index.html").read_text()
    assert 'id="smoke-warning"' in html and "data:image/png;base64," in html

    capsys.readouterr()
    assert main(args) == 0  # the study and the store hold everything: nothing is trained
    assert "training" not in capsys.readouterr().err
    assert json.loads((out / "summary.json").read_text())["rows"] == summary["rows"]


def test_a_failed_grid_point_is_trained_when_the_sweep_runs_again(tmp_path):
    store, out = tmp_path / "runs", tmp_path / "report"
    store.mkdir()
    grid = {"guide_threshold": [0.0, 1000000.0], "guide_noise_std": [0.1]}
    grid_id = hashlib.sha256(json.dumps([grid["guide_threshold"],
                                         grid["guide_noise_std"]]).encode()).hexdigest()[:8]
    study = optuna.create_study(
        study_name=f"ablate-threshold-smoke-MountainCarContinuous-v0-s1-{grid_id}",
        storage=f"sqlite:///{store / 'ablate-threshold.db'}", direction="maximize")
    study.add_trial(optuna.trial.create_trial(  # an earlier sitting failed at T2 = always
        state=optuna.trial.TrialState.FAIL,
        params={"guide_threshold": 1000000.0, "guide_noise_std": 0.1},
        distributions={k: optuna.distributions.CategoricalDistribution(v)
                       for k, v in grid.items()}))
    args = ["ablate-threshold", "--profile", "smoke", "--seeds", "1", "--store", str(store),
            "--out", str(out), "--thresholds", "0", "1000000"]
    assert main(args) == 0
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert [len(r["runs"]) for r in rows] == [1, 1]
