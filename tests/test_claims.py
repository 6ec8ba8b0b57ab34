"""Each claim's checks on synthetic run groups: they can pass, fail, or stay inconclusive."""

import numpy as np
import pytest

from replicate.claims import (ANT, CHEETAH, HOPPER, MOUNTAINCAR, WALKER, Group, claim_1,
                              claim_2, claim_3, claim_4, claim_5, claim_streams, instability,
                              judge_claims)


def group(env_id, algo, finals, curves=None):
    finals = np.asarray(finals, dtype=float)
    if curves is None:
        curves = np.linspace(0, 1, 5)[None, :] * finals[:, None]  # steady climbs
    return Group(env_id, algo, list(range(len(finals))), finals, np.asarray(curves, float))


def rng():
    return claim_streams(0, 1)


def test_instability_hand_computed():
    assert instability(np.array([0.0, 1.0, 2.0, 3.0])) == 0.0
    assert instability(np.array([0.0, 4.0, 0.0, 4.0])) == pytest.approx(1.0)  # drop 4 / range 4
    assert instability(np.array([2.0, 2.0])) == 0.0


def test_claim_1_reproduced_and_not():
    groups = {(MOUNTAINCAR, "drl-eg"): group(MOUNTAINCAR, "drl-eg", [95, 94, 96, 93]),
              (MOUNTAINCAR, "sac"): group(MOUNTAINCAR, "sac", [0, 0, -0.1, 0]),
              (MOUNTAINCAR, "ppo"): group(MOUNTAINCAR, "ppo", [1, -2, 0, 0.5]),
              (MOUNTAINCAR, "ddpgfd"): group(MOUNTAINCAR, "ddpgfd", [60, 70, 65, 50])}
    assert claim_1(groups, {}, rng())["verdict"] == "reproduced"
    groups[(MOUNTAINCAR, "ppo-bc")] = group(MOUNTAINCAR, "ppo-bc", [97, 97, 98, 97])
    claim = claim_1(groups, {}, rng())
    assert claim["verdict"] == "not reproduced"  # PPO+BC does not end below DRL-EG
    failing = [p["what"] for p in claim["parts"] if p["verdict"] == "not reproduced"]
    assert failing == ["PPO+BC ends below DRL-EG: DRL-EG minus PPO+BC above 0"]


def test_claim_2_equivalence_margin():
    same = {(e, a): group(e, a, [1000, 1010, 990, 1005]) for e in (HOPPER, CHEETAH)
            for a in ("sac", "drl-eg")}
    assert claim_2(same, {}, rng())["verdict"] == "reproduced"
    apart = dict(same)
    apart[(HOPPER, "drl-eg")] = group(HOPPER, "drl-eg", [2000, 2010, 1990, 2005])
    assert claim_2(apart, {}, rng())["verdict"] == "not reproduced"
    noisy = dict(same)
    noisy[(HOPPER, "drl-eg")] = group(HOPPER, "drl-eg", [600, 1400, 800, 1300])
    assert claim_2(noisy, {}, rng())["verdict"] == "inconclusive"


def test_claim_3_needs_demonstrations_and_judges_both_parts():
    groups = {(e, "drl-eg"): group(e, "drl-eg", [3800, 3900, 3850, 3950]) for e in (WALKER, ANT)}
    groups.update({(e, "sac"): group(e, "sac", [2000, 2500, 2200, 2100]) for e in (WALKER, ANT)})
    assert claim_3(groups, {}, rng())["verdict"].startswith("not judged")
    assert claim_3(groups, {WALKER: 4000, ANT: 4000}, rng())["verdict"] == "reproduced"
    assert claim_3(groups, {WALKER: 4000, ANT: 6000}, rng())["verdict"] == "not reproduced"


def test_claim_4_compares_instability():
    wobbly = np.array([[0, 100, 10, 100, 20], [0, 90, 5, 95, 30], [0, 80, 0, 90, 10]], float)
    steady = np.array([[0, 20, 40, 60, 80], [0, 25, 45, 70, 85], [0, 15, 35, 55, 75]], float)
    groups = {(ANT, "drl-eg"): group(ANT, "drl-eg", steady[:, -1], steady),
              (ANT, "sac"): group(ANT, "sac", wobbly[:, -1], wobbly),
              (ANT, "ddpgfd"): group(ANT, "ddpgfd", wobbly[:, -1], wobbly)}
    assert claim_4(groups, {}, rng())["verdict"] == "reproduced"
    swapped = {(ANT, "drl-eg"): groups[(ANT, "sac")], (ANT, "sac"): groups[(ANT, "drl-eg")],
               (ANT, "ddpgfd"): groups[(ANT, "drl-eg")]}
    assert claim_4(swapped, {}, rng())["verdict"] == "not reproduced"


def test_claim_5_pairs_seeds():
    groups = {(ANT, "drl-eg"): group(ANT, "drl-eg", [3000, 3100, 2900, 3050]),
              (ANT, "sac"): group(ANT, "sac", [900, 2800, 2700, 2950])}
    claim = claim_5(groups, {}, rng())
    assert claim["verdict"] == "reproduced"
    assert claim["parts"][1]["seeds_meeting"] == 1  # seed 0: SAC stuck below half


def test_claim_5_without_a_stuck_seed_needs_the_papers_four_pairs_to_say_not_reproduced():
    drl = [3000, 3100, 2900, 3050]
    sac = [2900, 2800, 2700, 2950]  # SAC never below half of DRL-EG
    four = {(ANT, "drl-eg"): group(ANT, "drl-eg", drl), (ANT, "sac"): group(ANT, "sac", sac)}
    assert claim_5(four, {}, rng())["parts"][1]["verdict"] == "not reproduced"
    three = {(ANT, "drl-eg"): group(ANT, "drl-eg", drl[:3]), (ANT, "sac"): group(ANT, "sac", sac[:3])}
    claim = claim_5(three, {}, rng())
    assert claim["parts"][1]["verdict"] == "inconclusive (3 of the paper's 4 paired seeds)"
    assert claim["verdict"] != "not reproduced"
    one = {(ANT, "drl-eg"): group(ANT, "drl-eg", drl[:1]), (ANT, "sac"): group(ANT, "sac", sac[:1])}
    claim = claim_5(one, {}, rng())
    assert claim["parts"][0]["what"] == ("Ant, 1 paired seed: DRL-EG minus SAC above 0 (no "
                                         "Wilcoxon signed-rank p: fewer than 2 pairs or no "
                                         "difference)")
    assert claim["algorithms"] == ["DRL-EG on Ant-v5 (1 seed)", "SAC on Ant-v5 (1 seed)"]


def test_missing_runs_and_meaningless_profiles_are_not_judged():
    ledger = judge_claims({}, {}, 0, meaningful=True)
    assert [c["id"] for c in ledger] == [1, 2, 3, 4, 5]
    assert all(c["verdict"].startswith("not judged: no runs of") for c in ledger)
    groups = {(MOUNTAINCAR, "drl-eg"): group(MOUNTAINCAR, "drl-eg", [95, 94])}
    smoke = judge_claims(groups, {}, 0, meaningful=False)
    assert smoke[0]["verdict"] == "not judged (smoke profile: numbers mean nothing)"


def test_mujoco_claims_judge_the_curves_and_state_what_the_budget_can_show():
    from replicate.claims import ANT, WALKER, Group, judge_claims

    steps = np.arange(0, 200_001, 50_000)
    rising = np.array([[0, 500, 1000, 1500, 2000.0]] * 3) + np.arange(3)[:, None]
    early = np.array([[0, 1500, 1900, 2000, 2000.0]] * 3) + np.arange(3)[:, None]
    groups = {}
    for env in (WALKER, ANT):
        # same final return, but DRL-EG gets there earlier: only the area tells them apart
        groups[(env, "sac")] = Group(env, "sac", [0, 1, 2], rising[:, -1], rising, steps)
        groups[(env, "drl-eg")] = Group(env, "drl-eg", [0, 1, 2], early[:, -1], early, steps)
    claim_3 = judge_claims(groups, {WALKER: 2000.0, ANT: 2000.0}, 0, True)[2]
    areas = [p for p in claim_3["parts"] if "area under the curve" in p["what"]]
    finals = [p for p in claim_3["parts"] if p["what"].endswith("SAC above 0")]
    assert len(areas) == 2 and all(p["verdict"] == "reproduced" for p in areas)
    assert all(p["verdict"] != "reproduced" for p in finals)  # equal ends: not above 0
    assert "200,000 steps" in claim_3["budget_note"]


def test_a_checks_interval_does_not_move_when_runs_for_another_check_arrive():
    """Claim 3 gains DDPGfD on Walker2d: its new checks appear, and every check it had keeps
    its interval to the last digit (each check bootstraps from a stream named by its label)."""
    rng_data = np.random.default_rng(4)
    groups = {}
    for env in (WALKER, ANT):
        for algo in ("sac", "drl-eg"):
            groups[(env, algo)] = group(env, algo, rng_data.normal(1000, 300, size=3))
    before = judge_claims(groups, {WALKER: 2000.0, ANT: 2000.0}, 0, True)[2]["parts"]
    groups[(WALKER, "ddpgfd")] = group(WALKER, "ddpgfd", rng_data.normal(4000, 100, size=3))
    after = judge_claims(groups, {WALKER: 2000.0, ANT: 2000.0}, 0, True)[2]["parts"]
    assert len(after) == len(before) + 2
    by_label = {p["what"]: p for p in after}
    for part in before:
        assert by_label[part["what"]] == part
