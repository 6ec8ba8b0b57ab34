"""Confirmatory plans: planned from open checks, registered in git, trained on fresh seeds
and judged on their own runs (smoke runs; a declaration whose checks are open on them)."""

import json
import os
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

from replicate.claims.confirm_judge import confirmatory_results, judge_plan, read_plan
from replicate.claims.declaration import load_declaration
from replicate.cli.main import main
from replicate.confirm.plan import plan_checks, used_seeds
from replicate.confirm.register import check_registered, plan_specs, run_ids, run_starts
from replicate.errors import HarnessError
from replicate.grids.profiles import get_profile

MC = "MountainCarContinuous-v0"
SMOKE = get_profile("smoke")


@pytest.fixture
def store(smoke_fig3, tmp_path):
    """A copy of the smoke Fig. 3 store (2 seeds per cell), free to add runs to."""
    copy = tmp_path / "runs"
    shutil.copytree(smoke_fig3[0], copy, ignore=shutil.ignore_patterns(".*"))
    return copy


@pytest.fixture
def declaration(store, tmp_path):
    """Two claims over the smoke runs whose checks stay open: each threshold 12 standard
    errors below the observed estimate (with 2 seeds, 1 degree of freedom, a one-sided test
    at 2.5% needs 12.7), and one check that fails, so an outcome can change a verdict."""
    from replicate.claims.groups import claim_groups
    from replicate.figures.fig3 import figure3_grid
    from replicate.stats import paired_mean_difference, t_mean
    from replicate.store.query import stored_runs

    groups = claim_groups(stored_runs(figure3_grid(SMOKE)[0], store))
    ppo_bc = t_mean(groups[(MC, "ppo-bc")].finals)
    diff = paired_mean_difference(groups[(MC, "drl-eg")].finals, groups[(MC, "sac")].finals)
    assert ppo_bc.se > 0 and diff.se > 0
    path = tmp_path / "open.toml"
    path.write_text(
        f"""
[paper]
key = "example"
title = "Checks left open on smoke runs"

[tests]
confidence = 0.95

[[claim]]
id = 1
title = "Guidance does not hurt"
source = "s"
quote = "q"

[[claim.part]]
id = "1a"
statement = "DRL-EG ends above SAC less a margin"
[[claim.part.check]]
kind = "difference"
algo = "drl-eg"
other = "sac"
env = "{MC}"
measure = "final_return"
above = {diff.value - 12 * diff.se!r}

[[claim]]
id = 2
title = "Pre-trained PPO"
source = "s"
quote = "q"

[[claim.part]]
id = "2a"
statement = "PPO with pre-training ends high"
[[claim.part.check]]
kind = "mean"
algo = "ppo-bc"
env = "{MC}"
measure = "final_return"
above = {ppo_bc.value - 12 * ppo_bc.se!r}

[[claim.part]]
id = "2b"
statement = "PPO learns alike with and without pre-training"
[[claim.part.check]]
kind = "difference"
algo = "ppo-bc"
other = "ppo"
env = "{MC}"
measure = "area"
within = [-50.0, 50.0]
"""
    )
    return path


def _git(root: Path, *args: str, date: str | None = None) -> None:
    env = dict(
        os.environ,
        GIT_AUTHOR_NAME="t",
        GIT_AUTHOR_EMAIL="t@example.org",
        GIT_COMMITTER_NAME="t",
        GIT_COMMITTER_EMAIL="t@example.org",
    )
    if date:
        env.update(GIT_AUTHOR_DATE=date, GIT_COMMITTER_DATE=date)
    subprocess.run(["git", "-C", str(root), *args], check=True, capture_output=True, env=env)


@pytest.fixture
def repo(tmp_path):
    root = tmp_path / "repo"
    (root / "plans").mkdir(parents=True)
    _git(root, "init", "-q")
    return root


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error: ")
    return err


def test_every_open_check_gets_a_plan_on_fresh_seeds(store, declaration, tmp_path):
    plans, without = plan_checks(SMOKE, store, load_declaration(declaration), tmp_path / "none")
    assert not without
    by_id = {p.check_id: p for p in plans}
    assert set(by_id) == {"1a.1", "2a.1"}  # 2b.1 fails: not open
    paired, mean = by_id["1a.1"], by_id["2a.1"]
    assert (
        paired.unit == "pairs" and paired.algos == ("drl-eg", "sac") and mean.algos == ("ppo-bc",)
    )
    for plan in plans:
        assert plan.outcome == "holds" and 2 <= plan.n <= 10 and plan.power >= 0.8
        assert plan.sigma_factor > 1  # the spread's upper limit, not its estimate
        assert plan.seeds == tuple(range(1000, 1000 + plan.n))
        assert plan.hours("cpu") > 0 and plan.hours("gpu") is None
        assert plan.runs == plan.n * len(plan.algos)
    # sorted by cost; the claim's verdict each outcome reaches
    assert [p.hours("cpu") for p in plans] == sorted(p.hours("cpu") for p in plans)
    assert mean.verdict_now == "not reproduced"
    assert mean.reachable == {"holds": "partly reproduced", "fails": "not reproduced"}
    assert paired.reachable == {"holds": "reproduced", "fails": "not reproduced"}


def test_seeds_are_disjoint_from_every_seed_the_store_holds(store, declaration, tmp_path):
    # an unfinished run at seed 1003 of one of the cells takes the first block
    (store / f".partial-sac__{MC}__s1003__0123456789ab").mkdir()
    plans, _ = plan_checks(SMOKE, store, load_declaration(declaration), tmp_path / "none")
    paired = next(p for p in plans if p.check_id == "1a.1")
    held = used_seeds(store, {(MC, "sac"), (MC, "drl-eg")}, None)
    assert {0, 1, 1003} <= held and not held & set(paired.seeds)
    assert paired.seeds[0] == 2000
    mean = next(p for p in plans if p.check_id == "2a.1")  # another cell: its first block
    assert mean.seeds[0] == 1000


def test_hours_refuses_a_plan_that_does_not_fit(store, declaration, repo, capsys):
    args = ["confirm", "--profile", "smoke", "--store", str(store)]
    args += ["--declaration", str(declaration), "--plans", str(repo / "plans")]
    assert main([*args, "--check", "2a.1", "--hours", "0.0001"]) == 2
    err = _one_error_line(capsys)
    assert "does not fit in 0.0001 h" in err and "env steps" in err and " h on a 2-core" in err
    assert not list((repo / "plans").iterdir())
    # the list leaves out what does not fit
    assert main([*args, "--hours", "0.0001"]) == 0
    assert "2 plan(s) need more than 0.0001 h" in capsys.readouterr().out


def test_a_plan_registered_committed_trained_and_judged(store, declaration, repo, capsys):
    args = ["confirm", "--profile", "smoke", "--store", str(store)]
    args += ["--declaration", str(declaration), "--plans", str(repo / "plans")]
    assert main(args) == 0
    listing = capsys.readouterr().out
    assert "2a.1" in listing and "1a.1" in listing and "partly reproduced if holds" in listing

    assert main([*args, "--check", "2:2a.1", "--hours", "5"]) == 0
    plan_file = repo / "plans" / "smoke-2a.1.toml"
    plan = read_plan(plan_file)
    with open(plan_file, "rb") as handle:
        assert tomllib.load(handle)["check"]["algo"] == "ppo-bc"
    assert plan["plan"]["claim"] == 2 and plan["test"]["level"] == 0.025
    assert plan["test"]["test"] == "one-sample t-test" and plan["test"]["powered_for"] == "holds"
    assert plan["runs"]["steps"] == 1200 and plan["runs"]["eval_interval"] == 400
    assert len(plan["exploratory"]["runs"]) == 2 and plan["exploratory"]["n"] == 2
    n = plan["test"]["n"]
    assert len(plan["runs"]["ids"]) == n and all("__s10" in i for i in plan["runs"]["ids"])

    # nothing trained yet: progress, no verdict
    result = judge_plan(plan, store)
    assert result["state"] is None and result["progress"] == {"done": 0, "planned": n}

    # rewritten until committed, on the same seeds
    assert main([*args, "--check", "2a.1"]) == 0
    assert read_plan(plan_file)["runs"]["seeds"] == plan["runs"]["seeds"]

    train = [*args, "--check", "2a.1", "--train", "--workers", "2"]
    assert main(train) == 2  # not committed yet
    assert "is not committed" in _one_error_line(capsys)
    _git(repo, "add", "plans")
    _git(repo, "commit", "-qm", "register 2a.1")
    assert main(train) == 0
    out = capsys.readouterr().out
    assert "smoke-2a.1.toml" in out
    result = judge_plan(plan, store)
    assert result["progress"] == {"done": n, "planned": n}
    assert result["state"] in ("holds", "fails", "inconclusive")
    assert result["low"] <= result["estimate"] <= result["high"]
    assert result["method"] == f"95% t-interval, n = {n}" and 0 <= result["p"] <= 1

    # it reads only its own runs: another run of the same cell changes nothing
    own = store / plan["runs"]["ids"][0]
    shutil.copytree(own, store / f"ppo-bc__{MC}__s1999__ffffffffffff")
    assert judge_plan(plan, store) == result
    assert confirmatory_results("smoke", store, repo / "plans") == {"2a.1": result}
    assert main([*args, "--status"]) == 0
    assert "2a.1" in (status := capsys.readouterr().out) and result["state"] in status

    # registered: never rewritten
    assert main([*args, "--check", "2a.1"]) == 2
    assert "already registered" in _one_error_line(capsys)

    # a plan edited after its runs began is refused, committed or not
    plan_file.write_text(plan_file.read_text().replace("n = ", "n =  ", 1))
    assert main(train) == 2
    assert "not committed" in _one_error_line(capsys)
    _git(repo, "commit", "-qam", "edit", date="2090-01-01T00:00:00+00:00")
    assert main(train) == 2
    assert "after its run" in _one_error_line(capsys)


def test_the_git_check_takes_the_repository_root(repo, tmp_path):
    plan_file = repo / "plans" / "smoke-1a.1.toml"
    plan_file.write_text("x = 1\n")
    store = tmp_path / "empty-store"
    with pytest.raises(HarnessError, match="not committed"):
        check_registered(plan_file, repo, store, [])
    _git(repo, "add", "plans")
    _git(repo, "commit", "-qm", "plan", date="2030-01-01T00:00:00+00:00")
    commit = check_registered(plan_file, repo, store, ["r1"])
    assert len(commit) == 40
    # a run that began before the commit
    (store / "r1").mkdir(parents=True)
    (store / "r1" / "provenance.json").write_text('{"started_utc": "2029-12-31T23:00:00+00:00"}')
    assert list(run_starts(store, ["r1"])) == ["r1"]
    with pytest.raises(HarnessError, match="after its run r1 began"):
        check_registered(plan_file, repo, store, ["r1"])


def test_a_plans_runs_are_the_grids_runs_at_other_seeds(store):
    """At the grid's own seeds a plan's specs give the very runs the Fig. 3 grid trained."""
    runs = {"grid": "fig3", "env": MC, "algos": ["ppo-bc", "drl-eg"], "seeds": [0, 1]}
    ids = run_ids(plan_specs({"path": "x", "runs": runs}, SMOKE))
    assert len(ids) == 4 and all((store / i / "provenance.json").is_file() for i in ids)


def test_reports_that_read_a_cells_runs_leave_a_plans_seeds_out(store):
    from replicate.figures.fig3 import figure3_grid
    from replicate.figures.guided_share import guided_runs
    from replicate.store.query import stored_runs

    source = next(store.glob(f"drl-eg__{MC}__s0__*"))
    copy = store / source.name.replace("__s0__", "__s1000__")
    shutil.copytree(source, copy)
    spec = json.loads((copy / "spec.json").read_text())
    (copy / "spec.json").write_text(json.dumps(dict(spec, seed=1000)))
    assert {r.spec["seed"] for r in guided_runs("smoke", store)} == {0, 1}
    assert {r.spec["seed"] for r in stored_runs(figure3_grid(SMOKE)[0], store)} == {0, 1}
