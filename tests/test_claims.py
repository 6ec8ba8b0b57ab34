"""Each claim's checks on synthetic run groups: the states a reviewer needs (reproduced,
partly reproduced, not reproduced, inconclusive, not testable at this budget), paired
differences where seeds are shared, and what would decide an open check."""

import numpy as np
import pytest

from replicate.checks import Check, Group, decide, instability
from replicate.claims import (
    ANT,
    CHEETAH,
    HOPPER,
    MOUNTAINCAR,
    WALKER,
    claim_1,
    claim_2,
    claim_3,
    claim_4,
    claim_5,
    judge_claims,
)
from replicate.stats import t_mean

DEMOS = {MOUNTAINCAR: 93.0, HOPPER: 3000.0, CHEETAH: 7000.0, WALKER: 4000.0, ANT: 4000.0}


def group(env_id, algo, finals, curves=None, steps=None):
    finals = np.asarray(finals, dtype=float)
    if curves is None:
        curves = np.linspace(0, 1, 5)[None, :] * finals[:, None]  # steady climbs
    return Group(
        env_id,
        algo,
        list(range(len(finals))),
        finals,
        np.asarray(curves, float),
        steps,
        {"cpu": 100.0},
    )


def test_instability_hand_computed():
    assert instability(np.array([0.0, 1.0, 2.0, 3.0])) == 0.0
    assert instability(np.array([0.0, 4.0, 0.0, 4.0])) == pytest.approx(1.0)  # drop 4 / range 4
    assert instability(np.array([2.0, 2.0])) == 0.0


def test_claim_1_is_partly_reproduced_when_only_a_secondary_check_fails():
    groups = {
        (MOUNTAINCAR, "drl-eg"): group(MOUNTAINCAR, "drl-eg", [95, 94, 96, 93]),
        (MOUNTAINCAR, "sac"): group(MOUNTAINCAR, "sac", [0, 0, -0.1, 0]),
        (MOUNTAINCAR, "ppo"): group(MOUNTAINCAR, "ppo", [1, -2, 0, 0.5]),
    }
    claim = claim_1(groups, DEMOS)
    assert claim["verdict"] == "reproduced"
    assert claim["parts"][0]["role"] == "primary"
    assert claim["parts"][0]["method"] == "95% paired t-interval, 4 pairs"
    groups[(MOUNTAINCAR, "ppo")] = group(MOUNTAINCAR, "ppo", [93, 92, 94, 95])  # PPO solves it
    claim = claim_1(groups, DEMOS)
    assert claim["verdict"] == "partly reproduced"
    assert claim["not_met"] == ["PPO final return within +-10"]


def test_a_negligible_difference_is_equivalent_not_better_or_worse():
    groups = {
        (MOUNTAINCAR, "drl-eg"): group(MOUNTAINCAR, "drl-eg", [95, 94, 96, 93, 94]),
        (MOUNTAINCAR, "sac"): group(MOUNTAINCAR, "sac", [0, 0, 0, 0, 0]),
        (MOUNTAINCAR, "ppo-bc"): group(MOUNTAINCAR, "ppo-bc", [96, 95, 97, 94, 95]),
    }
    claim = claim_1(groups, DEMOS)
    below = [p for p in claim["parts"] if p["what"].startswith("PPO+BC ends below")][0]
    assert below["verdict"] == "equivalent"  # -1 against a smallest effect of 9.3
    # "ends below DRL-EG" is not met by a negligible difference: the claim holds only partly
    assert claim["verdict"] == "partly reproduced"
    assert claim["not_met"] == [below["what"]]


def test_claim_2_equivalence_is_paired():
    sac = [1000, 2000, 1500, 1200]
    same = {}
    for env in (HOPPER, CHEETAH):
        same[(env, "sac")] = group(env, "sac", sac)
        same[(env, "drl-eg")] = group(env, "drl-eg", np.array(sac) + [5, -5, 10, 0])
    claim = claim_2(same, DEMOS)
    # the seeds' spread (1000-2000) would swamp an unpaired interval; paired it cancels
    assert claim["verdict"] == "reproduced"
    assert claim["effect"]["quantity"] == claim["parts"][0]["quantity"]["quantity"]
    assert claim["effect"]["low"] == claim["parts"][0]["low"]
    apart = dict(same)
    apart[(HOPPER, "drl-eg")] = group(HOPPER, "drl-eg", np.array(sac) + 900)
    assert claim_2(apart, DEMOS)["verdict"] == "not reproduced"
    noisy = dict(same)
    noisy[(HOPPER, "drl-eg")] = group(HOPPER, "drl-eg", np.array(sac) + [-600, 500, -300, 400])
    claim = claim_2(noisy, DEMOS)
    assert claim["verdict"] == "inconclusive"
    assert claim["parts"][0]["decide"]  # what would decide it is stated


def test_claim_3_demonstration_target_is_not_testable_where_no_published_sac_reaches_it():
    steps = np.arange(0, 200_001, 50_000)
    groups = {
        (e, "drl-eg"): group(e, "drl-eg", [3800, 3900, 3850, 3950], steps=steps)
        for e in (WALKER, ANT)
    }
    groups.update(
        {(e, "sac"): group(e, "sac", [2000, 2500, 2200, 2100], steps=steps) for e in (WALKER, ANT)}
    )
    assert claim_3(groups, {})["verdict"].startswith("not judged")
    claim = claim_3(groups, {WALKER: 4000, ANT: 8000})
    assert claim["verdict"] == "reproduced"
    target = [p for p in claim["parts"] if "demonstrations" in p["what"] and ANT in p["what"]][0]
    assert target["verdict"] == "not testable at this budget"
    assert "no published SAC reaches 7200 by 200,000 steps" in target["not_testable"]


def test_claim_4_compares_instability_paired():
    wobbly = np.array([[0, 100, 10, 100, 20], [0, 90, 5, 95, 30], [0, 80, 0, 90, 10]], float)
    steady = np.array([[0, 20, 40, 60, 80], [0, 25, 45, 70, 85], [0, 15, 35, 55, 75]], float)
    groups = {
        (ANT, "drl-eg"): group(ANT, "drl-eg", steady[:, -1], steady),
        (ANT, "sac"): group(ANT, "sac", wobbly[:, -1], wobbly),
        (ANT, "ddpgfd"): group(ANT, "ddpgfd", wobbly[:, -1], wobbly),
    }
    assert claim_4(groups, DEMOS)["verdict"] == "reproduced"
    swapped = {
        (ANT, "drl-eg"): groups[(ANT, "sac")],
        (ANT, "sac"): groups[(ANT, "drl-eg")],
        (ANT, "ddpgfd"): groups[(ANT, "drl-eg")],
    }
    assert claim_4(swapped, DEMOS)["verdict"] == "not reproduced"


def test_claim_5_needs_a_stuck_sac_seed():
    stuck = {
        (ANT, "drl-eg"): group(ANT, "drl-eg", [3000, 3100, 2900, 3050]),
        (ANT, "sac"): group(ANT, "sac", [900, 2800, 2700, 2950]),
    }
    claim = claim_5(stuck, DEMOS)
    assert claim["verdict"] == "reproduced"
    assert claim["parts"][0]["seeds_meeting"] == 1  # seed 0: SAC stuck, DRL-EG escaped
    assert claim["parts"][0]["decide"] is None and claim["decides"] == []  # decided
    kept = dict(stuck)
    kept[(ANT, "drl-eg")] = group(ANT, "drl-eg", [1000, 3100, 2900, 3050])
    assert claim_5(kept, DEMOS)["verdict"] == "not reproduced"  # stuck, and DRL-EG stays
    none_stuck = {
        (ANT, "drl-eg"): group(ANT, "drl-eg", [3000, 3100, 2900, 3050]),
        (ANT, "sac"): group(ANT, "sac", [2900, 2800, 2700, 2950]),
    }
    claim = claim_5(none_stuck, DEMOS)
    assert claim["verdict"] == "not testable at this budget"
    assert "no SAC seed is stuck" in claim["parts"][0]["decide"]
    assert claim["paired"]["method"] == "95% paired t-interval, 4 pairs"


def test_secondary_checks_are_holm_adjusted_and_primary_ones_are_not():
    values = np.array([1.0, 1.2, 1.1, 0.9, 1.3])  # one-sided p above 0 about 1e-4
    checks = [Check("primary", t_mean(values), above=0.0, primary=True)]
    checks += [Check(f"secondary {k}", t_mean(values - 0.8), above=0.0) for k in range(6)]
    decide(checks)
    raw = checks[1].p_values()["holds"]
    assert checks[0].adjusted["holds"] == pytest.approx(checks[0].p_values()["holds"])
    assert checks[1].adjusted["holds"] == pytest.approx(min(1.0, 6 * raw))
    assert raw < 0.025 and checks[1].state == "inconclusive"  # passes alone, not in a family


def test_two_primaries_fail_only_after_holm_and_ask_more_seeds_to_fail():
    """Claims judged on two envs: 'holds' needs both at the plain level, while either env
    failing would make the claim not reproduced, so "fails" is Holm-adjusted over the two,
    and what would decide a failing-side estimate is counted at that level."""
    from replicate.verdicts import what_would_decide

    below = t_mean(np.array([-0.2, -1.0, -1.6, -2.4, -0.8]))  # fails alone at p about 0.016
    above = t_mean(np.array([0.1, 0.3, 0.2, 0.4, 0.25]))  # holds
    one = Check("one env", below, above=0.0, primary=True)
    two = [
        Check("env a", below, above=0.0, primary=True),
        Check("env b", above, above=0.0, primary=True),
    ]
    decide([one])
    decide(two)
    assert one.state == "fails" and two[0].state == "inconclusive" and two[1].state == "holds"
    assert two[0].adjusted["fails"] == pytest.approx(2 * one.adjusted["fails"])
    open_one = Check(
        "open", t_mean(np.array([0.5, -1.0, -1.6, -2.4, 0.8])), above=0.0, primary=True
    )
    decide([open_one])
    alone = what_would_decide(open_one, family=0, primaries=1)[1]
    of_two = what_would_decide(open_one, family=0, primaries=2)[1]
    assert int(alone.split()[1]) < int(of_two.split()[1])  # "about N pairs"


def test_missing_runs_smoke_and_profiles_that_do_not_judge_mujoco():
    ledger = judge_claims({}, {}, meaningful=True, fig4_groups={})
    assert [c["id"] for c in ledger] == [1, 2, 3, 4, 5]
    assert all(c["verdict"].startswith("not judged: no runs of") for c in ledger)
    groups = {
        (MOUNTAINCAR, "drl-eg"): group(MOUNTAINCAR, "drl-eg", [95, 94]),
        (MOUNTAINCAR, "sac"): group(MOUNTAINCAR, "sac", [0, 0]),
    }
    smoke = judge_claims(groups, {}, meaningful=False)
    assert smoke[0]["verdict"] == "not judged (smoke profile: numbers mean nothing)"
    quick = judge_claims(groups, DEMOS, meaningful=True, judged_envs={MOUNTAINCAR})
    assert quick[0]["parts"]
    assert all(c["verdict"] == "not judged at this profile's budget" for c in quick[1:])


def test_a_checks_interval_does_not_move_when_runs_for_another_check_arrive():
    rng_data = np.random.default_rng(4)
    groups = {}
    for env in (WALKER, ANT):
        for algo in ("sac", "drl-eg"):
            groups[(env, algo)] = group(env, algo, rng_data.normal(1000, 300, size=3))
    before = judge_claims(groups, DEMOS, True)[2]["parts"]
    groups[(WALKER, "ddpgfd")] = group(WALKER, "ddpgfd", rng_data.normal(4000, 100, size=3))
    after = judge_claims(groups, DEMOS, True)[2]["parts"]
    assert len(after) == len(before) + 2
    by_label = {p["what"]: p for p in after}
    for part in before:
        assert (by_label[part["what"]]["low"], by_label[part["what"]]["high"]) == (
            part["low"],
            part["high"],
        )


def test_claim_2_moves_only_with_new_pairs():
    """SAC seeds without a DRL-EG partner change neither the paired estimate nor its margin."""
    sac = [1000, 2000, 1500]
    groups = {}
    for env in (HOPPER, CHEETAH):
        groups[(env, "sac")] = group(env, "sac", sac)
        groups[(env, "drl-eg")] = group(env, "drl-eg", np.array(sac) + [40, -60, 90])
    before = claim_2(groups, DEMOS)
    groups[(HOPPER, "sac")] = group(HOPPER, "sac", sac + [100, 150])  # two unpaired seeds
    after = claim_2(groups, DEMOS)
    assert [p["what"] for p in after["parts"]] == [p["what"] for p in before["parts"]]
    assert after["parts"][0]["low"] == before["parts"][0]["low"]
