import math

import numpy as np
import pytest

from baselines.common.checkpoint import load_checkpoint
from baselines.common.evaluation import evaluate
from baselines.ibrl import ImitationPolicy
from baselines.jsrl import (
    CURRICULUM_SEED_OFFSET,
    JSRLConfig,
    JumpStartExplorer,
    advances,
    guide_steps,
    jump_start_returns,
    measure_horizon,
)
from baselines.registry import get_algorithm
from baselines.sac_twin_q import TwinQSACAgent
from envs import make_env
from replicate.demos import default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR, TINY, batch_curves, curve_signature, train_tiny
from tests.test_resume import Killed, run

GUIDE_ACTION = 0.77


class ConstantGuide:
    def __call__(self, states: np.ndarray) -> np.ndarray:
        return np.full((len(states), 1), GUIDE_ACTION, dtype=np.float32)


def explorer(horizons=(5,), **overrides) -> JumpStartExplorer:
    """A constant guide per member and the learner's rule (no curriculum env needed)."""
    config = JSRLConfig(
        hidden_sizes=(8, 8),
        curriculum_stages=5,
        tolerance=0.05,
        curriculum_eval="learner",
        **overrides,
    )
    seeds = list(range(len(horizons)))
    agent = TwinQSACAgent(seeds, MOUNTAINCAR, config, cuda_graphs=False)
    guides = [ConstantGuide() for _ in seeds]
    return JumpStartExplorer(
        agent, guides, config, [None] * len(seeds), list(horizons), eval_episodes=1
    )


def test_guide_hands_over_to_the_learner_at_step_h_of_every_episode():
    jsrl = explorer(horizons=(5, 10))  # five stages: h = 5, 4, 3, 2, 1, 0 and 10, 8, ..., 0
    obs = np.array([[0.1, 0.2], [-0.3, 0.0]], dtype=np.float32)
    everyone = np.ones(2, dtype=bool)
    for stages, hs in (((0, 0), (5, 10)), ((2, 1), (3, 8)), ((5, 3), (0, 4))):
        jsrl.stage[:] = stages
        jsrl.episode_start(everyone)
        chosen = [jsrl.choose(obs) for _ in range(12)]
        for k, h in enumerate(hs):
            assert [guided[k] for _, guided in chosen] == [t < h for t in range(12)]
            assert all(a[k, 0] == np.float32(GUIDE_ACTION) for a, _ in chosen[:h])
            assert all(a[k, 0] != np.float32(GUIDE_ACTION) for a, _ in chosen[h:])
    jsrl.stage[:] = 0
    jsrl.episode_start(everyone)
    jsrl.stage[:] = 4  # a change of stage waits for the next episode
    assert all(jsrl.choose(obs)[1][0] for _ in range(5)) and not jsrl.choose(obs)[1][0]
    # a member's episode starts alone: only its count restarts, with its new h
    jsrl.episode_start(np.array([True, False]))  # member 0: h = 1; member 1 at step 6 of 10
    assert jsrl.choose(obs)[1].tolist() == [True, True]
    assert jsrl.choose(obs)[1].tolist() == [False, True]
    assert jsrl.choose(obs)[1].tolist() == [False, True]
    assert jsrl.choose(obs)[1].tolist() == [False, True]
    assert jsrl.choose(obs)[1].tolist() == [False, False]


def test_h_falls_from_the_horizon_to_zero_in_the_stages():
    assert [guide_steps(100, k, 4) for k in range(6)] == [100, 75, 50, 25, 0, 0]
    assert [guide_steps(7, k, 3) for k in range(4)] == [7, 5, 2, 0]


def test_stage_advances_when_the_return_is_within_tolerance_of_the_best_before_it():
    assert not advances(10.0, None, 0.05)  # the first evaluation only sets the best
    assert advances(9.5, 10.0, 0.05) and not advances(9.49, 10.0, 0.05)
    assert advances(-10.5, -10.0, 0.05) and not advances(-10.6, -10.0, 0.05)
    jsrl = explorer(horizons=(10, 10))  # five stages: h = 10, 8, 6, 4, 2, 0
    hs = []
    for t, mean_return in enumerate((10.0, 9.6, 5.0, 9.5, 12.0, 11.3, 11.5, 0.0, 20.0, 30.0)):
        jsrl.after_eval(0, mean_return)
        jsrl.after_eval(1, 10.0 - t)  # each 10% or more below the best: member 1 stays
        hs.append((jsrl.h(0), jsrl.h(1)))
    # member 0: 10 sets the best; 9.6 is within 5%: h 8; 5 is not; 9.5 is: 6; 12 is: 4
    # (best 12); 11.3 < 11.4 is not; 11.5 is: 2; 0 is not; 20: 0, where the curriculum stops
    assert [h for h, _ in hs] == [10, 8, 8, 6, 4, 4, 2, 2, 0, 0]
    assert [h for _, h in hs] == [10] * 10  # each member's stage moves on its own returns
    assert jsrl.best == [20.0, 10.0]


def test_jump_start_evaluation_and_horizon_follow_the_guide_then_the_learner():
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    imitation = ImitationPolicy(JSRLConfig(), demos, -np.ones(1), np.ones(1), seed=0)
    guide = lambda obs: imitation(obs[None])[0]  # noqa: E731
    idle = lambda obs: np.zeros(1, np.float32)  # noqa: E731
    # this env's first three guide episodes last 999 (stalled), 126 and 199 steps
    horizon = measure_horizon(make_env(MOUNTAINCAR, seed=CURRICULUM_SEED_OFFSET), guide, 3)
    assert horizon == 199  # the median
    # guided throughout, an episode is the guide's; never guided, it idles at no cost
    guided = jump_start_returns(make_env(MOUNTAINCAR, seed=5), guide, idle, 999, 2)
    assert guided == evaluate(make_env(MOUNTAINCAR, seed=5), guide, 2)
    assert jump_start_returns(make_env(MOUNTAINCAR, seed=5), guide, idle, 0, 2) == [0.0, 0.0]
    # guided for 10 steps of +-0.5 (cost 0.1 a^2 each), then idle: the learner took step 10
    ten = jump_start_returns(make_env(MOUNTAINCAR, seed=5), guide, idle, 10, 1)[0]
    assert ten == pytest.approx(-10 * 0.1 * 0.5**2)


def test_the_rule_judges_the_jump_started_policy_by_default():
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    config = JSRLConfig(hidden_sizes=(8, 8))
    agent = TwinQSACAgent([0, 1], MOUNTAINCAR, config, cuda_graphs=False)
    guides = [ImitationPolicy(config, demos, -np.ones(1), np.ones(1), seed=s) for s in (0, 1)]
    envs = [make_env(MOUNTAINCAR, seed=3), make_env(MOUNTAINCAR, seed=4)]
    jsrl = JumpStartExplorer(agent, guides, config, envs, horizons=[40, 30], eval_episodes=2)
    jsrl.after_eval(1, 12345.0)  # the learner's own return is not what the rule sees
    expected = jump_start_returns(
        make_env(MOUNTAINCAR, seed=4),
        lambda obs: guides[1](obs[None])[0],
        lambda obs: agent.act_member_deterministic(1, obs),
        30,
        2,
    )
    assert jsrl.best[1] == pytest.approx(np.mean(expected)) and jsrl.best[1] != 12345.0
    assert jsrl.best[0] is None  # member 0 has not been judged


def test_jsrl_trains_deterministically_and_moves_h_down():
    settings = {"curriculum_stages": 2, "tolerance": 100.0}  # every evaluation advances
    first, replay = train_tiny("jsrl", seed=2, steps=600, **settings)
    second, _ = train_tiny("jsrl", seed=2, steps=600, **settings)
    assert curve_signature(first) == curve_signature(second)
    buffer = replay.member(0)
    # the curve is the learner's own: at step 0 it equals twin-Q SAC's with the same seed
    sac, _ = train_tiny("sac-twin-q", seed=2, steps=1)
    assert first[0].returns == sac[0].returns
    # h is H until the evaluation at 200 (the one at 0 only sets the best), then H/2, each
    # episode keeping the h it started with; the guide's noise-free actions are the
    # MountainCar rule's +-0.5, the learner's are not
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    imitation = ImitationPolicy(JSRLConfig(), demos, -np.ones(1), np.ones(1), seed=0)
    horizon = measure_horizon(
        make_env(MOUNTAINCAR, seed=2 + CURRICULUM_SEED_OFFSET),
        lambda obs: imitation(obs[None])[0],
        5,
    )
    is_guide = np.isin(np.round(buffer.actions[:600, 0], 6), [-0.5, 0.5])
    ends = [i + 1 for i in np.flatnonzero(buffer.terminated[:600])]
    starts = [0, *ends]
    assert len(starts) >= 3 and 200 <= starts[-1] < 400  # episodes begin in both stages
    for start, end in zip(starts, [*ends, 600]):
        h = horizon if start < 200 else round(horizon / 2)
        assert start + h < end  # the learner takes over within each of these episodes
        assert is_guide[start : min(start + h, end)].all()
        assert not is_guide[start + h : end].any()


def test_config_refuses_an_unknown_curriculum_evaluation():
    with pytest.raises(ValueError, match="curriculum_eval"):
        JSRLConfig(curriculum_eval="guide")


def test_killed_jsrl_run_resumes_with_its_h(tmp_path):
    # Hopper ends episodes quickly (checkpoints before the kill); a large tolerance moves h
    # at every evaluation, so the resumed run must restore h to follow the curve
    overrides = {"hidden_sizes": (16, 16), "curriculum_stages": 4, "tolerance": 100.0}
    reference, reference_replay, _ = run("jsrl", "Hopper-v5", 600, **overrides)
    checkpoint = tmp_path / "checkpoint.pt"
    with pytest.raises(Killed):
        run("jsrl", "Hopper-v5", 600, checkpoint_path=checkpoint, kill_at=450, **overrides)
    saved = load_checkpoint(checkpoint)["explorer"]
    horizon = saved["horizons"][0]
    assert saved["stage"][0] >= 1 and guide_steps(horizon, saved["stage"][0], 4) < horizon
    resumed, resumed_replay, resumed_from = run(
        "jsrl", "Hopper-v5", 600, checkpoint_path=checkpoint, **overrides
    )
    assert 150 < resumed_from < 450
    assert curve_signature(resumed) == curve_signature(reference)
    assert resumed_replay.size == reference_replay.size == 600
    assert np.array_equal(resumed_replay.member(0).actions, reference_replay.member(0).actions)


def test_a_seed_batch_gives_each_member_the_curve_of_its_run_alone(tmp_path):
    # the curriculum moves (every evaluation advances), so each member's h, guide, curriculum
    # env and noise must be its own for its curve to match its batch of one
    settings = {"curriculum_stages": 2, "tolerance": 100.0}
    config = get_algorithm("jsrl").make_config({**TINY, **settings})
    batch = batch_curves("jsrl", config, tmp_path / "batch.pt", seeds=(0, 1), steps=400)
    for seed in (0, 1):
        alone, _ = train_tiny("jsrl", seed=seed, steps=400, **settings)
        # the same evaluation steps and guide shares (the same h, episode by episode); the
        # returns within rounding, since a stack of one multiplies with other kernels than
        # a stack of two (as for every algorithm of the family; tests/test_offpolicy.py)
        ours, theirs = curve_signature(batch[seed]), curve_signature(alone)
        assert [(s, g) for s, _, g, _ in ours] == [(s, g) for s, _, g, _ in theirs]
        for mine, own in zip(batch[seed], alone):
            assert mine.returns == pytest.approx(own.returns, rel=1e-5, abs=1e-6)
            # the training episodes' return too: their actions differ in the last bits
            assert (mine.train_return is None or math.isnan(mine.train_return)) == (
                own.train_return is None or math.isnan(own.train_return)
            )
            if own.train_return == own.train_return:
                assert mine.train_return == pytest.approx(own.train_return, rel=1e-5, abs=1e-6)
    assert curve_signature(batch[0]) != curve_signature(batch[1])
    # in batches of two, a member's curve is bit for bit the same whoever its neighbour is
    beside = batch_curves("jsrl", config, tmp_path / "beside.pt", seeds=(5, 1), steps=400)
    assert curve_signature(beside[1]) == curve_signature(batch[1])
