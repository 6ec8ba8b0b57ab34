"""The declared claims judged on synthetic run groups: parts and their states, every part
counting towards the verdict, margins fixed by the declaration, preconditions, Holm over a
claim's checks, what would decide an open check; and a second paper's declaration."""

from pathlib import Path

import numpy as np
import pytest

from replicate.claims.checks import Check, Group, decide
from replicate.claims.declaration import DeclarationError, load_declaration
from replicate.claims.judge import judge_claim, judge_claims
from replicate.claims.verdicts import claim_verdict, part_state, what_would_decide
from replicate.stats import t_mean
from replicate.store.measures import final_returns, instabilities, instability, late_window

MOUNTAINCAR, HOPPER, WALKER, CHEETAH, ANT = (
    "MountainCarContinuous-v0",
    "Hopper-v5",
    "Walker2d-v5",
    "HalfCheetah-v5",
    "Ant-v5",
)
DECLARATION = load_declaration()
STEPS = np.arange(0, 200_001, 50_000)


def group(env_id, algo, finals, curves=None, steps=STEPS):
    """Runs whose curves climb steadily to ``finals`` (flat over the late window)."""
    finals = np.asarray(finals, dtype=float)
    if curves is None:
        curves = np.minimum(np.linspace(0, 2, len(steps)), 1.0)[None, :] * finals[:, None]
    return Group(
        env_id,
        algo,
        list(range(len(finals))),
        final_returns(steps, curves),
        np.asarray(curves, float),
        steps,
        {"cpu": 100.0},
    )


def judged(claim_id, groups):
    return judge_claim(DECLARATION.claim(claim_id), groups, DECLARATION.confidence)


def part(claim, part_id):
    return next(p for p in claim["parts"] if p["id"] == part_id)


def test_instability_after_the_first_tenth_of_the_budget():
    assert instability(np.array([0.0, 1.0, 2.0, 3.0])) == 0.0
    assert instability(np.array([0.0, 4.0, 0.0, 4.0])) == pytest.approx(1.0)  # drop 4 / range 4
    steps = np.arange(0, 101, 10)
    curve = np.array([[100.0, 0, 10, 20, 30, 40, 50, 60, 70, 80, 90]])  # the first fall only
    assert instabilities(steps, curve)[0] == 0.0


def test_the_final_return_is_the_late_training_mean():
    steps = np.arange(0, 200_001, 5_000)
    assert late_window(steps, 0.10, 3).sum() == 4  # 185k, 190k, 195k, 200k
    assert late_window(np.array([0, 100, 200]), 0.10, 3).sum() == 3  # at least the last 3
    curve = np.zeros((1, len(steps)))
    curve[0, -4:] = [100, 200, 300, 400]
    assert final_returns(steps, curve)[0] == pytest.approx(250.0)


def test_every_part_counts_towards_claim_1():
    groups = {
        (MOUNTAINCAR, "drl-eg"): group(MOUNTAINCAR, "drl-eg", [95, 94, 96, 93, 95]),
        (MOUNTAINCAR, "sac"): group(MOUNTAINCAR, "sac", [0, 0, -0.1, 0, 0.05]),
        (MOUNTAINCAR, "ppo"): group(MOUNTAINCAR, "ppo", [1, -2, 0, 0.5, 0.2]),
        (MOUNTAINCAR, "ppo-bc"): group(MOUNTAINCAR, "ppo-bc", [60, 62, 58, 61, 59]),
        (MOUNTAINCAR, "ddpgfd"): group(MOUNTAINCAR, "ddpgfd", [50, 52, 49, 51, 48]),
    }
    claim = judged(1, groups)
    assert [p["state"] for p in claim["parts"]] == ["holds"] * 4
    assert claim["verdict"] == "reproduced"
    groups[(MOUNTAINCAR, "ppo")] = group(MOUNTAINCAR, "ppo", [93, 92, 94, 95, 93])  # solves it
    claim = judged(1, groups)
    assert part(claim, "1a")["state"] == "contradicted"
    assert "PPO final return within" in part(claim, "1a")["decided_by"]
    assert claim["verdict"] == "partly reproduced"


def test_a_claim_with_a_contradicted_part_is_never_inconclusive_or_reproduced():
    rng = np.random.default_rng(7)
    groups = {}
    for env in (WALKER, ANT):
        groups[(env, "sac")] = group(env, "sac", rng.normal(1000, 400, size=5))
        groups[(env, "drl-eg")] = group(env, "drl-eg", rng.normal(1000, 400, size=5))
    groups[(WALKER, "ddpgfd")] = group(WALKER, "ddpgfd", rng.normal(4000, 100, size=5))
    claim = judged(3, groups)
    assert part(claim, "3a")["state"] == "contradicted"  # DDPGfD far ahead on Walker2d
    assert "holds" not in [p["state"] for p in claim["parts"]]
    assert claim["verdict"] == "not reproduced"
    assert claim_verdict(["holds", "contradicted", "open"]) == "partly reproduced"
    assert claim_verdict(["open", "contradicted"]) == "not reproduced"
    assert claim_verdict(["holds", "open"]) == "inconclusive"
    assert part_state([("holds", False), ("fails", True)]) == "contradicted"
    assert part_state([("holds", False), ("inconclusive", False)]) == "open"


def test_margins_do_not_move_when_the_judged_runs_do():
    sac = np.array([1000.0, 2000, 1500, 1200, 1700])
    groups = {}
    for env in (HOPPER, CHEETAH):
        groups[(env, "sac")] = group(env, "sac", sac)
        groups[(env, "drl-eg")] = group(env, "drl-eg", sac + [5, -5, 10, 0, 3])
    before = judged(2, groups)
    for env in (HOPPER, CHEETAH):  # SAC three times as good, DRL-EG beside it
        groups[(env, "sac")] = group(env, "sac", 3 * sac)
        groups[(env, "drl-eg")] = group(env, "drl-eg", 3 * sac + [5, -5, 10, 0, 3])
    after = judged(2, groups)
    bands = [[c["band"] for c in p["checks"]] for p in before["parts"]]
    assert bands == [[c["band"] for c in p["checks"]] for p in after["parts"]]
    assert bands[0][0] == [-300.5, 300.5]  # 10% of the Hopper demonstrations' return
    assert before["verdict"] == after["verdict"] == "reproduced"  # paired: the spread cancels


def test_claim_5_is_not_testable_without_a_stuck_sac_seed():
    stuck = {
        (ANT, "drl-eg"): group(ANT, "drl-eg", [3000, 3100, 2900, 3050]),
        (ANT, "sac"): group(ANT, "sac", [900, 2800, 2700, 2950]),
    }
    claim = judged(5, stuck)
    assert claim["preconditions"][0]["observed"]
    assert part(claim, "5a")["state"] == "holds"  # seed 0: SAC stuck, DRL-EG escaped
    kept = {**stuck, (ANT, "drl-eg"): group(ANT, "drl-eg", [1000, 3100, 2900, 3050])}
    assert part(judged(5, kept), "5a")["state"] == "contradicted"
    none_stuck = {**stuck, (ANT, "sac"): group(ANT, "sac", [2900, 2800, 2700, 2950])}
    claim = judged(5, none_stuck)
    assert claim["verdict"] == "not testable at this budget"
    assert "no SAC seed stays stuck" in claim["preconditions"][0]["detail"]
    assert claim["paired"]["method"] == "95% paired t-interval, 4 pairs"


def test_every_check_of_a_claim_is_holm_adjusted():
    values = np.array([1.0, 1.2, 1.1, 0.9, 1.3])
    checks = [Check(f"check {k}", t_mean(values - 0.8), above=0.0) for k in range(6)]
    decide(checks)
    raw = checks[0].p_values()["holds"]
    assert checks[0].adjusted["holds"] == pytest.approx(min(1.0, 6 * raw))
    assert raw < 0.025 and checks[0].state == "inconclusive"  # passes alone, not in a family


def test_what_would_decide_says_which_way_and_a_range():
    leaning_down = Check("open", t_mean(np.array([0.5, -1.0, -1.6, -2.4, 0.8])), above=0.0)
    decide([leaning_down])
    text, short = what_would_decide(leaning_down, family=1)
    assert leaning_down.likely == "fails" and "likely fails" in short
    low, high = [int(n) for n in short.split("(")[1].split(")")[0].split(" to ")]
    plug_in = int(short.split()[0].lstrip("~"))
    assert low <= plug_in <= high and low < high
    _, of_four = what_would_decide(leaning_down, family=4)
    assert int(of_four.split()[0].lstrip("~")) > plug_in  # a larger family asks more seeds


def test_missing_runs_smoke_and_profiles_that_do_not_judge_mujoco():
    ledger = judge_claims({}, meaningful=True, fig4_groups={})
    assert [c["id"] for c in ledger] == [1, 2, 3, 4, 5]
    assert all(c["verdict"] in ("inconclusive", "not testable at this budget") for c in ledger)
    assert all(k["verdict"] == "no runs" for p in ledger[0]["parts"] for k in p["checks"])
    groups = {(MOUNTAINCAR, "drl-eg"): group(MOUNTAINCAR, "drl-eg", [95, 94])}
    smoke = judge_claims(groups, meaningful=False)
    assert smoke[0]["verdict"] == "not judged (smoke profile: numbers mean nothing)"
    quick = judge_claims(groups, meaningful=True, judged_envs={MOUNTAINCAR})
    assert quick[0]["parts"][0]["checks"]
    assert all(c["verdict"] == "not judged at this profile's budget" for c in quick[1:])


def test_the_declared_margins_are_derived_from_the_committed_demonstrations():
    from replicate.demos import default_demo_path, load_demos

    for env, declared in DECLARATION.demonstrations.items():
        demos = load_demos(default_demo_path(env), env)
        assert declared == pytest.approx(demos.mean_return, abs=1e-3)
    for spec in DECLARATION.claims:
        for check in spec.checks:
            if check.smallest_effect and check.measure != "instability":
                demo = DECLARATION.demonstrations[check.env]
                assert check.smallest_effect == pytest.approx(0.1 * demo, abs=0.05)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ('other = "sac"', 'other = "sax"'),
        ('measure = "area"', 'measure = "areas"'),
        ("above = -9.589", "above = -9.589, within = [0, 1]"),
        ('id = "2b"\nstatement = "PPO with pre-training ends above 0"\ncheck = [', None),
    ],
)
def test_a_malformed_declaration_names_its_claim_and_field(tmp_path, edit, message):
    text = (Path(__file__).parent / "data" / "two_claims.toml").read_text()
    if message is None:  # a part with no check
        start = text.index('id = "2b"')
        text = text[:start] + 'id = "2b"\nstatement = "nothing to check"\n'
    else:
        text = text.replace(edit, message, 1)
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(DeclarationError) as error:
        load_declaration(bad)
    line = str(error.value)
    assert "\n" not in line and line.startswith("bad.toml: claim ")
    assert ("part 2b" in line) if message is None else ("field" in line)


def test_a_second_paper_declared_the_same_way_judges_smoke_runs(smoke_fig3):
    from replicate.claims.groups import claim_groups
    from replicate.store.runs import completed_runs

    store, _ = smoke_fig3
    declaration = load_declaration(Path(__file__).parent / "data" / "two_claims.toml")
    groups = claim_groups(completed_runs(store))
    ledger = judge_claims(groups, meaningful=True, declaration=declaration)
    assert [c["id"] for c in ledger] == [1, 2]
    assert [p["id"] for p in ledger[1]["parts"]] == ["2a", "2b"]
    for claim in ledger:
        for p in claim["parts"]:
            assert p["state"] in ("holds", "contradicted", "open")
            assert all(k["verdict"] != "no runs" for k in p["checks"])
    assert ledger[0]["parts"][0]["checks"][0]["method"].startswith("90% paired")


def test_a_check_reads_only_its_own_groups():
    rng = np.random.default_rng(4)
    groups = {}
    for env in (WALKER, ANT):
        for algo in ("sac", "drl-eg"):
            groups[(env, algo)] = group(env, algo, rng.normal(1000, 300, size=3))
    before = {k["what"]: k for p in judged(3, groups)["parts"] for k in p["checks"]}
    groups[(WALKER, "ddpgfd")] = group(WALKER, "ddpgfd", rng.normal(4000, 100, size=3))
    after = {k["what"]: k for p in judged(3, groups)["parts"] for k in p["checks"]}
    for what, check in before.items():
        if check["verdict"] != "no runs":
            assert (after[what]["low"], after[what]["high"]) == (check["low"], check["high"])


def test_a_confirmatory_result_decides_its_check_and_an_unfinished_one_does_not():
    sac = np.array([1000.0, 2000, 1500, 1200, 1700])
    groups = {}
    for env in (HOPPER, CHEETAH):
        groups[(env, "sac")] = group(env, "sac", sac)
        groups[(env, "drl-eg")] = group(env, "drl-eg", sac + [600, -500, 300, -400, 100])
    exploratory = judged(2, groups)
    assert part(exploratory, "2b")["checks"][0]["verdict"] == "inconclusive"
    unfinished = {"2b.1": {"state": None, "progress": {"done": 3, "planned": 34}}}
    claim = judge_claim(DECLARATION.claim(2), groups, DECLARATION.confidence, unfinished)
    check = part(claim, "2b")["checks"][0]
    assert check["verdict"] == "inconclusive" and check["confirmatory"]["progress"]["done"] == 3
    assert claim["confirmatory"] == []
    failed = {"2b.1": {"state": "fails", "progress": {"done": 34, "planned": 34}}}
    claim = judge_claim(DECLARATION.claim(2), groups, DECLARATION.confidence, failed)
    check = part(claim, "2b")["checks"][0]
    assert (check["verdict"], check["exploratory"]) == ("fails", "inconclusive")
    assert part(claim, "2b")["state"] == "contradicted" and claim["confirmatory"] == ["2b.1"]
    assert claim["verdict"] == "not reproduced"
