"""The smoke profile end to end: grid -> run store -> statistics -> figure -> HTML."""

import json
import re

import numpy as np

from replicate.cli.main import main
from replicate.figures.fig3 import FIG3_ALGORITHMS
from replicate.grids.drl_eg_settings import DRL_EG_ENV_DEFAULTS


def test_smoke_profile_produces_a_self_contained_report(smoke_fig3, capsys, tmp_path):
    store, out = smoke_fig3
    html = (out / "index.html").read_text()
    for section in (
        "claims",
        "figure",
        "final-returns",
        "budgets",
        "demonstrations",
        "runs",
        "provenance",
        "smoke-warning",
    ):
        assert f'id="{section}"' in html
    image = re.search(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)
    assert image and len(image.group(1)) > 1000
    assert "http://" not in html and "https://" not in html  # nothing fetched at view time
    assert "not judged (smoke profile" in html
    assert "<th>Device</th>" in html and "<td>cpu</td>" in html  # where each run trained
    summary = json.loads((out / "summary.json").read_text())
    assert {f["algo"] for f in summary["final_returns"]} == set(FIG3_ALGORITHMS)
    assert len(summary["runs"]) == 2 * len(FIG3_ALGORITHMS) and not summary["failed"]
    checks = " ".join(" ".join(part["declared"]) for part in summary["claims"][0]["parts"])
    for label in ("DRL-EG", "SAC", "PPO", "PPO+BC", "DDPGfD"):
        assert label in checks
    assert all(len(f["finals"]) == 2 for f in summary["final_returns"])
    # the ledger names the T2 each DRL-EG cell trained with, read from its runs' specs
    assert 'id="guidance"' in html
    guidance = {g["algo"]: g for g in summary["guidance"]}
    assert guidance["drl-eg"]["t2"] == [
        DRL_EG_ENV_DEFAULTS["MountainCarContinuous-v0"]["guide_threshold"]
    ]
    assert guidance["drl-eg-gmm"]["t2"] == [] and not guidance["drl-eg-gmm"]["uses_t2"]
    assert all(0 <= share <= 1 for g in guidance.values() for share in g["guided_share"])
    assert len(guidance["drl-eg"]["guided_share"]) == guidance["drl-eg"]["runs"]

    # a second invocation trains nothing and rebuilds the same numbers from the store
    capsys.readouterr()
    assert main(["fig3", "--profile", "smoke", "--store", str(store), "--out", str(out)]) == 0
    assert f"{2 * len(FIG3_ALGORITHMS)} already in" in capsys.readouterr().out
    again = json.loads((out / "summary.json").read_text())
    assert again["final_returns"] == summary["final_returns"]
    assert again["claims"] == summary["claims"]

    # the report command rebuilds the same numbers from the store alone, and every other
    # report it can: Fig. 3's DRL-EG runs are the ablation's point at the default T2
    rebuilt_dir = tmp_path / "rebuilt"
    assert (
        main(["report", "--profile", "smoke", "--store", str(store), "--out", str(rebuilt_dir)])
        == 0
    )
    rebuilt = json.loads((rebuilt_dir / "fig3" / "summary.json").read_text())
    assert rebuilt["final_returns"] == summary["final_returns"]
    assert (
        "rebuilt from the run store without training"
        in (rebuilt_dir / "fig3" / "index.html").read_text()
    )
    ablation = json.loads((rebuilt_dir / "ablate-threshold" / "summary.json").read_text())
    assert [(r["threshold"], len(r["runs"])) for r in ablation["rows"]] == [(0.05, 2)]
    assert (rebuilt_dir / "table1" / "index.html").is_file()
    assert not (rebuilt_dir / "fig4").exists()  # no Fig. 4 runs: nothing written


def test_report_from_an_empty_store_leaves_the_figures_alone(tmp_path, capsys):
    out = tmp_path / "report"
    (out / "fig3").mkdir(parents=True)
    (out / "fig3" / "index.html").write_text("a committed report")
    assert (
        main(["report", "--profile", "smoke", "--store", str(tmp_path / "none"), "--out", str(out)])
        == 0
    )
    assert (out / "fig3" / "index.html").read_text() == "a committed report"
    printed = capsys.readouterr().out
    assert "fig3: no runs of the smoke profile" in printed and "left as it is" in printed
    assert (out / "table1" / "index.html").is_file()  # Table 1 needs no runs


def test_published_sac_sits_beside_ours_at_the_same_steps():
    from replicate.claims.checks import Group
    from replicate.claims.published import published_points
    from replicate.figures.fig3 import efficiency_rows
    from replicate.reports.pages import published_rows

    steps = np.array([0, 100_000, 200_000])
    curves = np.array([[0, 900, 2000.0], [0, 1100, 2400.0]])
    groups = {("Ant-v5", "sac"): Group("Ant-v5", "sac", [0, 1], curves[:, -1], curves, steps)}
    rows = published_rows(groups, {"Ant-v5": 200_000})
    tianshou = [r for r in rows if r["source"] == "tianshou"]
    assert [r["steps"] for r in tianshou] == [100_000, 200_000]  # none beyond our budget
    assert tianshou[1]["ours"]["mean"] == 2200.0 and tianshou[1]["ours"]["n"] == 2
    assert tianshou[1]["mean"] == 2133.0 and tianshou[1]["family"] == "twin-Q SAC"
    same = [r for r in rows if r["source"] == "spinningup"]  # V-network SAC, as ours
    assert [(r["steps"], r["mean"]) for r in same] == [(200_000, 793.0)]
    assert {p.source for p in published_points("Ant-v5", 200_000)} == {"tianshou", "spinningup"}
    from replicate.experts import expert_training_curve

    expert = expert_training_curve("Ant-v5")  # the committed expert's own training run
    at = dict(zip(expert["steps"], expert["returns"]))
    assert [r["expert_run"]["return"] for r in tianshou] == [at[100_000], at[200_000]]
    assert tianshou[0]["expert_run"]["algo"] == "sac-twin-q"
    assert expert_training_curve("MountainCarContinuous-v0") is None  # no expert file
    walker = {
        ("Walker2d-v5", "sac"): Group("Walker2d-v5", "sac", [0, 1], curves[:, -1], curves, steps)
    }
    by_steps = {
        r["steps"]: r["expert_run"] for r in published_rows(walker, {"Walker2d-v5": 200_000})
    }
    trained = expert_training_curve("Walker2d-v5")  # the best of a seed batch, 180k steps
    assert by_steps[100_000]["best_of"] == trained["best_of"] > 1
    assert (by_steps[200_000] is None) == (200_000 not in trained["steps"])
    reach = efficiency_rows(groups, {"Ant-v5": 4400.0})[0]["reach"]
    assert reach == {"n": 1, "half_of_seeds": 200_000, "fastest": 200_000, "slowest": 200_000}
    # one fast seed of three does not make the cell fast: half of them never get there
    fast_one = np.array([[0, 2300, 2400.0], [0, 900, 1000.0], [0, 800, 900.0]])
    groups = {
        ("Ant-v5", "sac"): Group("Ant-v5", "sac", [0, 1, 2], fast_one[:, -1], fast_one, steps)
    }
    reach = efficiency_rows(groups, {"Ant-v5": 4400.0})[0]["reach"]
    assert reach["n"] == 1 and reach["fastest"] == 100_000 and reach["half_of_seeds"] is None


def test_a_cells_intervals_do_not_move_when_other_cells_join_the_report():
    from replicate.claims.groups import claim_groups
    from replicate.figures.fig3 import efficiency_rows, summarise
    from tests.test_rlfd import _run

    cell = [_run("sac", seed, [0.0, 40.0 + 7 * seed, 60.0 + 11 * seed]) for seed in range(4)]
    other = [_run("ppo", seed, [0.0, 10.0 * seed, 30.0 - seed]) for seed in range(4)]
    alone, joined = summarise(cell)[1][0], summarise(other + cell)[1]
    assert [(f.low, f.high) for f in joined if f.algo == "sac"] == [(alone.low, alone.high)]
    demo = {"MountainCarContinuous-v0": 95.0}
    area = efficiency_rows(claim_groups(cell), demo)[0]["area"]
    assert [
        r["area"] for r in efficiency_rows(claim_groups(other + cell), demo) if r["algo"] == "sac"
    ] == [area]


def test_report_replaces_superseded_runs_but_never_builds_from_fewer(smoke_fig3, tmp_path, capsys):
    store, _ = smoke_fig3
    out = tmp_path / "report"
    assert main(["report", "--profile", "smoke", "--store", str(store), "--out", str(out)]) == 0
    summary_file = out / "fig3" / "summary.json"
    summary = json.loads(summary_file.read_text())
    real = summary["run_ids"][0]
    assert summary["run_ids"] == [r["run_id"] for r in summary["runs"]]
    # a run it names was superseded (its spec changed): as many runs as before, so rebuilt
    summary["run_ids"][0] = real[:-12] + "0" * 12
    summary_file.write_text(json.dumps(summary))
    capsys.readouterr()
    assert main(["report", "--profile", "smoke", "--store", str(store), "--out", str(out)]) == 0
    assert "1 of the" in capsys.readouterr().out
    rebuilt = json.loads(summary_file.read_text())
    assert rebuilt["run_ids"][0] == real and not list(out.glob(".*rebuild"))
    # it names a run the store cannot replace: the store gives fewer, so it stays
    rebuilt["run_ids"].append("sac__lost__s9__" + "1" * 12)
    summary_file.write_text(json.dumps(rebuilt))
    assert main(["report", "--profile", "smoke", "--store", str(store), "--out", str(out)]) == 0
    assert "left as it is" in capsys.readouterr().out
    assert json.loads(summary_file.read_text()) == rebuilt


def test_fig3_trains_only_the_chosen_cells_and_reports_the_whole_grid(
    smoke_fig3, tmp_path, capsys, monkeypatch
):
    import shutil

    trained, _ = smoke_fig3
    store, out = tmp_path / "runs", tmp_path / "report"
    shutil.copytree(trained, store)
    for algo in ("sac", "ppo"):  # two cells of the grid not trained yet
        for run in store.glob(f"{algo}__*"):
            shutil.rmtree(run)
    before = sorted(p.name for p in store.iterdir())

    capsys.readouterr()
    assert (
        main(
            [
                "fig3",
                "--profile",
                "smoke",
                "--store",
                str(store),
                "--out",
                str(out),
                "--algos",
                "sac",
                "--dry-run",
            ]
        )
        == 0
    )
    plan = capsys.readouterr().out
    assert "2 to train" in plan and "sac" in plan and " ppo " not in plan
    assert plan.rstrip().endswith("one run per process")
    assert (
        main(
            [
                "fig3",
                "--profile",
                "smoke",
                "--store",
                str(store),
                "--out",
                str(out),
                "--algos",
                "sac",
                "ppo",
                "--batch",
                "2",
                "--dry-run",
            ]
        )
        == 0
    )
    plan = capsys.readouterr().out  # SAC's two seeds batch; PPO has no batched trainer
    assert plan.rstrip().endswith("2 runs in 1 seed batch, 2 runs one per process")
    assert sorted(p.name for p in store.iterdir()) == before and not out.exists()

    assert (
        main(
            [
                "fig3",
                "--profile",
                "smoke",
                "--store",
                str(store),
                "--out",
                str(out),
                "--algos",
                "sac",
                "--envs",
                "MountainCarContinuous-v0",
            ]
        )
        == 0
    )
    assert len(list(store.glob("sac__*"))) == 2 and not list(store.glob("ppo__*"))
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["runs"]) == 2 * len(FIG3_ALGORITHMS) - 2  # every run of the grid
    assert [(s["algo"], s["reason"][:12]) for s in summary["skipped"]] == [
        ("ppo", "seeds 0, 1 n")
    ]  # one line per cell, with the seeds it lacks

    # a store that holds only this machine's share never replaces a report naming more runs
    share = tmp_path / "share"
    share.mkdir()
    for run in store.glob("sac__*"):
        shutil.copytree(run, share / run.name)
    capsys.readouterr()
    assert (
        main(
            [
                "fig3",
                "--profile",
                "smoke",
                "--store",
                str(share),
                "--out",
                str(out),
                "--algos",
                "sac",
            ]
        )
        == 0
    )
    assert "left as it is" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text()) == summary

    capsys.readouterr()
    assert (
        main(["fig3", "--profile", "smoke", "--store", str(store), "--algos", "sax", "--dry-run"])
        == 2
    )
    error = capsys.readouterr().err
    assert "--algos: sax not in this grid" in error and "ppo-bc" in error
    from replicate.grids import drl_eg_settings

    monkeypatch.setattr(drl_eg_settings, "MUJOCO_T2_RULE", None)  # as before the rule was fixed
    assert (
        main(
            [
                "fig3",
                "--profile",
                "reduced",
                "--store",
                str(store),
                "--algos",
                "drl-eg",
                "--envs",
                "Ant-v5",
                "--dry-run",
            ]
        )
        == 2
    )
    assert "wait for the MuJoCo T2 rule" in capsys.readouterr().err
    # the cells skipped for the rule are printed only where the selection reaches them
    reduced = ["fig3", "--profile", "reduced", "--store", str(store), "--dry-run"]
    assert main(reduced) == 0
    assert "skipped drl-eg on Ant-v5" in capsys.readouterr().out
    assert main(reduced + ["--algos", "ppo", "--envs", "MountainCarContinuous-v0"]) == 0
    assert "skipped" not in capsys.readouterr().out
