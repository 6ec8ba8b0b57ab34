import json

import numpy as np
import pandas as pd
import pytest

from replicate.cli.main import main
from replicate.errors import HarnessError
from replicate.figures.rlfd import (
    CURVE_FRACTIONS,
    SPARSE_TASKS,
    compare,
    normalised,
    random_return,
    rlfd_grid,
)
from replicate.grids.profiles import get_profile
from replicate.store.runner import Run

TASK = "MountainCarContinuous-v0"
DEMO = 95.0


def _run(algo: str, seed: int, returns: list[float]) -> Run:
    steps = np.linspace(0, 1000, len(returns)).astype(int)
    curve = pd.DataFrame({"step": steps, "return_mean": returns})
    provenance = {"demos": {"expert_return_mean": DEMO}}
    return Run(
        __import__("pathlib").Path(f"{algo}__{TASK}__s{seed}"),
        {"env_id": TASK, "algo": algo, "seed": seed},
        curve,
        provenance,
    )


def test_normalised_scores_put_random_at_0_and_the_demonstrations_at_1():
    np.testing.assert_allclose(
        normalised(np.array([-10.0, 40.0, 90.0]), -10.0, 90.0), [0.0, 0.5, 1.0]
    )
    with pytest.raises(HarnessError, match="not above random"):
        normalised(np.array([1.0]), 5.0, 5.0)


def test_rlpd_backs_up_the_entropy_except_on_sparse_reward_tasks():
    # as RLPD's official runs: off on its sparse tasks, the config's default elsewhere
    specs, _ = rlfd_grid(get_profile("reduced"), seeds=1, algorithms=("rlpd",))
    backup = {spec.env_id: spec.hyperparameters.get("backup_entropy") for spec in specs}
    assert {env for env, value in backup.items() if value is False} == set(SPARSE_TASKS)
    assert all(backup[env] is None for env in backup if env not in SPARSE_TASKS)


def test_compare_judges_drl_eg_against_each_method_per_task():
    late = [90.0, 90.0, 90.0]  # the final return averages the last 3 evaluations
    runs = [_run("drl-eg", s, [0, 20, 40, 50 + s] + [x + s for x in late]) for s in range(4)]
    runs += [_run("sac", s, [0] * 6 + [s * 0.1]) for s in range(4)]  # learns nothing
    runs += [_run("ibrl", s, [0, 60, 80, 85] + [x + s for x in late]) for s in range(4)]
    result = compare(runs, {TASK: (1000, 500)}, 0)
    verdicts = {v["other"]: v["verdict"] for v in result["verdicts"]}
    assert verdicts == {"sac": "DRL-EG better", "ibrl": "equivalent"}  # the same ends, paired
    random = random_return(TASK)
    assert result["reference"][TASK] == {"random": random, "demo": DEMO}
    sac = next(c for c in result["cells"] if c["algo"] == "sac")
    # the final return: the mean of the last 3 evaluations
    assert sac["final_normalised"] == pytest.approx((0.05 - random) / (DEMO - random))
    aggregate = result["aggregate"]
    assert aggregate["runs_per_task"] == 4 and aggregate["tasks"] == [TASK]
    # the sample-efficiency curve sees IBRL ahead halfway through, DRL-EG's IQM at the end
    value = dict(zip(CURVE_FRACTIONS, aggregate["efficiency"]["ibrl"][0]))
    assert value[0.5] > dict(zip(CURVE_FRACTIONS, aggregate["efficiency"]["drl-eg"][0]))[0.5]
    improvement = {p["other"]: p["value"] for p in aggregate["improvement"]}
    assert improvement["sac"] == 1.0 and 0.0 < improvement["ibrl"] < 1.0
    # a method added later leaves the differences already there as they were (their
    # Holm-adjusted p-values grow with the family, as multiplicity control requires)
    more = compare(
        runs + [_run("jsrl", s, [0, 50, 60, 70] + [x - 10 + s for x in late]) for s in range(4)],
        {TASK: (1000, 500)},
        0,
    )

    def stated(verdicts):
        return [(v["quantity"]["quantity"], v["effect"], v["low"], v["high"]) for v in verdicts]

    assert stated(v for v in more["verdicts"] if v["other"] != "jsrl") == stated(result["verdicts"])


def test_each_profile_report_points_to_the_other_profiles_comparisons(tmp_path):
    from replicate.figures.rlfd import _other_profiles

    for built in ("reports/rlfd", "reports/reduced/rlfd"):  # the paper one was never built
        (tmp_path / built).mkdir(parents=True)
        (tmp_path / built / "index.html").write_text("<html></html>")
    quick = {o["name"]: o for o in _other_profiles("quick", tmp_path / "reports" / "rlfd")}
    assert set(quick) == {"reduced", "paper"}  # never the smoke one, nor itself
    assert quick["reduced"]["href"] == "../reduced/rlfd/index.html"
    assert quick["reduced"]["path"] == "reports/reduced/rlfd/index.html"
    assert SPARSE_TASKS[0] in quick["reduced"]["tasks"]
    back = {
        o["name"]: o["href"]
        for o in _other_profiles("reduced", tmp_path / "reports" / "reduced" / ".rlfd.rebuild")
    }
    assert back == {"quick": "../../rlfd/index.html", "paper": None}  # no link to nowhere
    # written elsewhere (--out), the other reports are not beside it: no link, only the path
    elsewhere = _other_profiles("reduced", tmp_path / "out" / "quick" / "rlfd")
    assert [o["href"] for o in elsewhere] == [None, None]


@pytest.mark.slow
def test_smoke_comparison_trains_every_method_and_writes_the_report(tmp_path, capsys):
    store, out = tmp_path / "runs", tmp_path / "rlfd"
    args = [
        "compare-rlfd",
        "--profile",
        "smoke",
        "--seeds",
        "2",
        "--store",
        str(store),
        "--out",
        str(out),
        "--device",
        "cpu",
    ]
    assert main(args + ["--algos", "jsrl", "--dry-run"]) == 0
    assert "jsrl" in capsys.readouterr().out and not store.exists() and not out.exists()
    assert main(args + ["--algos", "jsrl"]) == 0  # one method first: the report says what lacks
    partial = json.loads((out / "summary.json").read_text())
    assert {c["algo"] for c in partial["cells"] if c["n"]} == {"jsrl"}
    assert {s["algo"] for s in partial["skipped"]} == {"sac", "drl-eg", "ibrl", "rlpd", "ddpgfd"}
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert {c["algo"] for c in summary["cells"]} == {
        "sac",
        "drl-eg",
        "ibrl",
        "rlpd",
        "jsrl",
        "ddpgfd",
    }
    assert all(c["n"] == 2 for c in summary["cells"]) and not summary["skipped"]
    assert len(summary["verdicts"]) == 5
    html = (out / "index.html").read_text()
    assert 'id="smoke-warning"' in html and "data:image/png;base64," in html
    assert 'id="guidance"' in html and [g["t2"] for g in summary["guidance"]] == [[0.05]]
    assert "<code>reports/reduced/rlfd/index.html</code> (not built here)" in html
    from replicate.figures.rlfd import rebuild_rlfd

    rebuilt = rebuild_rlfd("smoke", store, tmp_path / "again")
    again = json.loads((rebuilt.parent / "summary.json").read_text())
    assert again["cells"] == summary["cells"] and again["verdicts"] == summary["verdicts"]
