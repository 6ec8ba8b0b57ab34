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
from baselines.sac_twin_q import TwinQSACAgent
from envs import make_env
from replicate.demos import default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR, curve_signature, train_tiny
from tests.test_resume import Killed, run

GUIDE_ACTION = 0.77


class ConstantGuide:
    def __call__(self, states: np.ndarray) -> np.ndarray:
        return np.full((len(states), 1), GUIDE_ACTION, dtype=np.float32)


def explorer(horizon: int = 5, **overrides) -> JumpStartExplorer:
    config = JSRLConfig(
        hidden_sizes=(8, 8),
        curriculum_stages=5,
        tolerance=0.05,
        curriculum_eval="learner",
        **overrides,
    )
    agent = TwinQSACAgent(2, 1, -np.ones(1), np.ones(1), config, seed=0)
    return JumpStartExplorer(
        agent, ConstantGuide(), config, curriculum_env=None, horizon=horizon, eval_episodes=1
    )


def test_guide_hands_over_to_the_learner_at_step_h_of_every_episode():
    jsrl = explorer(horizon=5)
    obs = np.array([0.1, 0.2], dtype=np.float32)
    for stage, h in ((0, 5), (2, 3), (5, 0)):
        jsrl.stage = stage
        jsrl.episode_start()
        chosen = [jsrl.choose(obs) for _ in range(8)]
        assert [guided for _, guided in chosen] == [t < h for t in range(8)]
        assert all(a[0] == np.float32(GUIDE_ACTION) for a, _ in chosen[:h])
        assert all(a[0] != np.float32(GUIDE_ACTION) for a, _ in chosen[h:])
    jsrl.stage = 0
    jsrl.episode_start()
    jsrl.stage = 4  # a change of stage waits for the next episode
    assert all(jsrl.choose(obs)[1] for _ in range(5)) and not jsrl.choose(obs)[1]


def test_h_falls_from_the_horizon_to_zero_in_the_stages():
    assert [guide_steps(100, k, 4) for k in range(6)] == [100, 75, 50, 25, 0, 0]
    assert [guide_steps(7, k, 3) for k in range(4)] == [7, 5, 2, 0]


def test_stage_advances_when_the_return_is_within_tolerance_of_the_best_before_it():
    assert not advances(10.0, None, 0.05)  # the first evaluation only sets the best
    assert advances(9.5, 10.0, 0.05) and not advances(9.49, 10.0, 0.05)
    assert advances(-10.5, -10.0, 0.05) and not advances(-10.6, -10.0, 0.05)
    jsrl = explorer(horizon=10)  # five stages: h = 10, 8, 6, 4, 2, 0
    hs = []
    for mean_return in (10.0, 9.6, 5.0, 9.5, 12.0, 11.3, 11.5, 0.0, 20.0, 30.0):
        jsrl.after_eval(mean_return)
        hs.append(jsrl.h)
    # 10 sets the best; 9.6 is within 5%: h 8; 5 is not; 9.5 is: 6; 12 is: 4 (best 12);
    # 11.3 < 11.4 is not; 11.5 is: 2; 0 is not; 20: 0, where the curriculum stops
    assert hs == [10, 8, 8, 6, 4, 4, 2, 2, 0, 0]


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
    agent = TwinQSACAgent(2, 1, -np.ones(1), np.ones(1), config, seed=0)
    guide = ImitationPolicy(config, demos, -np.ones(1), np.ones(1), seed=0)
    jsrl = JumpStartExplorer(
        agent, guide, config, make_env(MOUNTAINCAR, seed=3), horizon=40, eval_episodes=2
    )
    jsrl.after_eval(12345.0)  # the learner's own return is not what the rule sees
    expected = jump_start_returns(
        make_env(MOUNTAINCAR, seed=3),
        jsrl.act_guide,
        lambda obs: agent.act(obs, deterministic=True),
        40,
        2,
    )
    assert jsrl.best == pytest.approx(np.mean(expected)) and jsrl.best != 12345.0


def test_jsrl_trains_deterministically_and_moves_h_down():
    settings = {"curriculum_stages": 2, "tolerance": 100.0}  # every evaluation advances
    first, buffer = train_tiny("jsrl", seed=2, steps=600, **settings)
    second, _ = train_tiny("jsrl", seed=2, steps=600, **settings)
    assert curve_signature(first) == curve_signature(second)
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
    reference, reference_buffer, _ = run("jsrl", "Hopper-v5", 600, **overrides)
    checkpoint = tmp_path / "checkpoint.pt"
    with pytest.raises(Killed):
        run("jsrl", "Hopper-v5", 600, checkpoint_path=checkpoint, kill_at=450, **overrides)
    saved = load_checkpoint(checkpoint)["explorer"]
    assert saved["stage"] >= 1 and saved["h"] < saved["horizon"]
    resumed, resumed_buffer, resumed_from = run(
        "jsrl", "Hopper-v5", 600, checkpoint_path=checkpoint, **overrides
    )
    assert 150 < resumed_from < 450
    assert curve_signature(resumed) == curve_signature(reference)
    assert np.array_equal(resumed_buffer.actions[:600], reference_buffer.actions[:600])
