import json

import numpy as np
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
    assert [r["label"] for r in summary["rows"]] == ["0 (never)", "always"]
    assert all(len(r["runs"]) == 1 and np.isfinite(r["final"]["mean"]) for r in summary["rows"])
    assert (store / "ablate-threshold.db").is_file()
    html = (out / "index.html").read_text()
    assert 'id="smoke-warning"' in html and "data:image/png;base64," in html

    capsys.readouterr()
    assert main(args) == 0  # the study and the store hold everything: nothing is trained
    assert "training" not in capsys.readouterr().err
    assert json.loads((out / "summary.json").read_text())["rows"] == summary["rows"]
