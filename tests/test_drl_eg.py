import numpy as np
import pytest
import torch

from baselines.drl_eg import (
    DRLEGConfig,
    demo_state_spacing,
    fit_gmm,
    fit_neural_guider,
    functional_discriminator,
    functional_guider,
    gmm_discriminator,
    nearest_demo,
)
from replicate.demos import default_demo_path, load_demos
from tests.helpers import MOUNTAINCAR, curve_signature, train_tiny


def test_nearest_demo_hand_computed():
    demo_states = np.array([[0.0, 0.0], [3.0, 4.0], [1.0, 1.0]])
    distance, index = nearest_demo(demo_states, np.array([3.0, 3.0]))
    # distances: sqrt(18) = 4.24, 1, sqrt(8) = 2.83
    assert index == 1 and distance == pytest.approx(1.0)


def test_discriminator_guides_at_and_below_threshold_only():
    assert functional_discriminator(1.0, threshold=1.0)
    assert functional_discriminator(0.3, threshold=1.0)
    assert not functional_discriminator(1.0, threshold=0.99)
    # T2 = 0 is "off", even for a state identical to a demonstration state
    assert not functional_discriminator(0.0, threshold=0.0)


class _StillAgent:
    """An agent whose policy always proposes zeros: what the explorer chose is visible."""

    def __init__(self, act_dim: int):
        self.act_dim = act_dim

    def act(self, obs, need=None):
        return np.zeros((len(obs), self.act_dim), dtype=np.float32)


def _guide(config, demos, state, low, high):
    """G(s) for one state from DRL-EG's explorer, or None where D(s) = 0."""
    from baselines.drl_eg import GuidedExplorer

    explorer = GuidedExplorer(_StillAgent(len(low)), [config], demos, low, high, [0])
    actions, guided = explorer.choose(np.asarray(state, dtype=np.float32)[None])
    return actions[0] if guided[0] else None


def test_zero_threshold_does_not_guide_a_state_equal_to_a_demonstration_state():
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    wall = demos.observations[0].copy()
    low, high = np.array([-1.0]), np.array([1.0])
    assert _guide(DRLEGConfig(guide_threshold=0.0), demos, wall, low, high) is None
    assert _guide(DRLEGConfig(guide_threshold=1e-9), demos, wall, low, high) is not None


def test_guider_returns_nearest_action_plus_gaussian_noise_clipped():
    demo_actions = np.array([[0.5, -0.2], [0.9, 0.95]])
    low, high = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    rng = np.random.default_rng(0)
    exact = functional_guider(demo_actions, 0, 0.0, rng, low, high)
    np.testing.assert_allclose(exact, [0.5, -0.2], atol=1e-7)
    samples = np.stack(
        [functional_guider(demo_actions, 0, 0.1, rng, low, high) for _ in range(4000)]
    )
    np.testing.assert_allclose(samples.mean(0), [0.5, -0.2], atol=0.01)
    np.testing.assert_allclose(samples.std(0), [0.1, 0.1], atol=0.01)
    clipped = np.stack(
        [functional_guider(demo_actions, 1, 0.5, rng, low, high) for _ in range(200)]
    )
    assert clipped.max() <= 1.0 and clipped.min() >= -1.0


def test_demo_state_spacing_is_the_median_nearest_neighbour_distance():
    states = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [3.0, 4.0]])
    # nearest other: 0->1 (1), 1->0 (1), 2->1 (2), 3->2 (4): median of [1, 1, 2, 4] = 1.5
    assert demo_state_spacing(states) == pytest.approx(1.5)
    with pytest.raises(ValueError):
        demo_state_spacing(states[:1])


def test_envs_without_a_chosen_t2_take_it_from_their_demonstrations(monkeypatch, tmp_path):
    from replicate import demos as demos_module
    from replicate.grids import drl_eg_settings

    assert (
        drl_eg_settings.drl_eg_env_defaults(MOUNTAINCAR)
        == drl_eg_settings.DRL_EG_ENV_DEFAULTS[MOUNTAINCAR]
    )
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    monkeypatch.delitem(drl_eg_settings.DRL_EG_ENV_DEFAULTS, MOUNTAINCAR)
    chosen = drl_eg_settings.drl_eg_env_defaults(MOUNTAINCAR)
    spacing = demo_state_spacing(demos.observations.astype(np.float64))
    assert chosen["guide_threshold"] == pytest.approx(spacing, rel=1e-3)
    assert 0 < chosen["guide_threshold"] < 0.05  # a MountainCar step moves far less than 0.05
    missing = tmp_path / "none.npz"
    monkeypatch.setattr(demos_module, "default_demo_path", lambda env_id: missing)
    with pytest.raises(Exception, match="none.npz"):
        drl_eg_settings.drl_eg_env_defaults(MOUNTAINCAR)


def test_config_rejects_negative_threshold():
    with pytest.raises(ValueError):
        DRLEGConfig(guide_threshold=-1.0)


def test_zero_threshold_never_guides_so_drl_eg_equals_sac():
    sac_curve, _ = train_tiny("sac", seed=5, steps=400)
    drl_curve, _ = train_tiny("drl-eg", seed=5, steps=400, guide_threshold=0.0)
    assert [p.returns for p in drl_curve] == [p.returns for p in sac_curve]
    assert all(p.guided_fraction == 0.0 for p in drl_curve[1:])


def test_large_threshold_guides_every_step_and_stores_the_executed_action():
    curve, replay = train_tiny(
        "drl-eg",
        seed=0,
        steps=400,
        guide_threshold=1e6,
        guide_noise_std=0.0,
        learning_starts=10_000,
    )
    buffer = replay.member(0)
    assert curve[1].guided_fraction == 1.0 and curve[1].gate_open
    # with sigma = 0 the executed (and stored) action is the MountainCar rule's +-0.5
    stored = buffer.actions[:400, 0]
    assert set(np.round(stored, 6)) <= {-0.5, 0.5}


def test_gate_closes_when_the_policy_beats_the_demonstrations(monkeypatch):
    from replicate import demos as demos_module

    original = demos_module.load_demos

    def weak_demos(path, env_id):
        loaded = original(path, env_id)
        loaded.metadata = dict(loaded.metadata, expert_return_mean=-1e9)
        return loaded

    monkeypatch.setattr("tests.helpers.load_demos", weak_demos)
    curve, _ = train_tiny("drl-eg", seed=0, steps=400, guide_threshold=1e6)
    assert all(p.guided_fraction == 0.0 for p in curve[1:])
    assert all(p.gate_open is False for p in curve)


def test_same_seed_same_drl_eg_curve():
    first, _ = train_tiny("drl-eg", seed=1, steps=400)
    second, _ = train_tiny("drl-eg", seed=1, steps=400)
    assert curve_signature(first) == curve_signature(second)


def test_gmm_threshold_is_the_chosen_quantile_of_demo_densities():
    rng = np.random.default_rng(0)
    demo_states = rng.normal(size=(400, 2))
    gmm, log_threshold = fit_gmm(demo_states, components=2, threshold_quantile=0.25, seed=0)
    guided = [gmm_discriminator(gmm, s, log_threshold) for s in demo_states]
    assert np.mean(guided) == pytest.approx(0.75, abs=0.01)
    assert not gmm_discriminator(gmm, np.array([8.0, 8.0]), log_threshold)  # far away
    assert gmm_discriminator(gmm, np.array([0.0, 0.0]), log_threshold)  # at the mode


def test_neural_guider_learns_the_mountaincar_rule():
    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    net = fit_neural_guider(demos, hidden=(32, 32), steps=1500, seed=0)
    states = torch.tensor([[-0.5, -0.03], [-0.5, 0.03]])
    with torch.no_grad():
        predicted = net(states).numpy()[:, 0]
    assert predicted[0] < -0.3 and predicted[1] > 0.3  # the rule says -0.5 and +0.5


def test_neural_guider_leaves_the_policy_initial_weights_alone():
    first, _ = train_tiny("drl-eg", seed=3, steps=200, guide_threshold=0.0)
    second, _ = train_tiny(
        "drl-eg",
        seed=3,
        steps=200,
        guide_threshold=0.0,
        discriminator="gmm",
        gmm_threshold_quantile=1.0,
        guider="neural",
        neural_guider_steps=10,
        neural_guider_hidden=(8,),
    )
    # a quantile of 1 makes the GMM discriminator guide nowhere, so both runs are SAC
    assert [p.returns for p in first] == [p.returns for p in second]


def test_gmm_variant_is_registered_and_deterministic():
    first, _ = train_tiny("drl-eg-gmm", seed=2, steps=300, gmm_components=2)
    second, _ = train_tiny("drl-eg-gmm", seed=2, steps=300, gmm_components=2)
    assert curve_signature(first) == curve_signature(second)
    assert first[1].guided_fraction > 0.0  # the gate is open at the start and demos are near


def test_unknown_discriminator_is_refused():
    with pytest.raises(ValueError, match="discriminator must be one of"):
        DRLEGConfig(discriminator="kde")


def test_kd_tree_guidance_finds_the_brute_force_nearest_demo():
    from baselines.drl_eg import GuidedExplorer
    from replicate.demos import Demonstrations

    rng = np.random.default_rng(0)
    states = rng.normal(size=(5000, 11)).astype(np.float32)
    demos = Demonstrations(
        states, rng.uniform(-1, 1, (5000, 3)).astype(np.float32), {"expert_return_mean": 1.0}
    )
    config = DRLEGConfig(guide_threshold=1e6, guide_noise_std=0.0)
    explorer = GuidedExplorer(_StillAgent(3), [config], demos, -np.ones(3), np.ones(3), [0])
    for query in rng.normal(size=(200, 11)):
        distance, index = nearest_demo(explorer.states, query)
        tree_distance, tree_index = explorer.tree.query(query)
        assert tree_index == index and tree_distance == pytest.approx(distance)
        actions, guided = explorer.choose(query[None].astype(np.float32))
        assert guided[0] and np.allclose(actions[0], demos.actions[index])


def test_guidance_on_twin_q_sac_is_off_at_zero_and_guides_at_a_large_threshold():
    sac_curve, _ = train_tiny("sac-twin-q", seed=5, steps=400)
    off_curve, _ = train_tiny("drl-eg-twin-q", seed=5, steps=400, guide_threshold=0.0)
    assert [p.returns for p in off_curve] == [p.returns for p in sac_curve]
    guided, replay = train_tiny(
        "drl-eg-twin-q", seed=5, steps=400, guide_threshold=1e6, guide_noise_std=0.0
    )
    assert guided[1].guided_fraction == 1.0
    assert set(np.round(replay.member(0).actions[:400, 0], 6)) <= {-0.5, 0.5}


def test_neural_guider_seeds_the_cpu_stream_alone_and_as_before(monkeypatch):
    """Its initial weights are those torch.manual_seed(seed) gives, drawn without touching
    any CUDA generator, so that a CPU run on a GPU machine starts no CUDA context."""
    from baselines.common.networks import mlp

    demos = load_demos(default_demo_path(MOUNTAINCAR), MOUNTAINCAR)
    forked = []
    fork = torch.random.fork_rng
    monkeypatch.setattr(
        torch.random, "fork_rng", lambda *a, **k: forked.append(k.get("devices")) or fork(*a, **k)
    )
    net = fit_neural_guider(demos, hidden=(8,), steps=0, seed=5)
    assert forked == [[]]
    before = torch.random.get_rng_state()
    torch.manual_seed(5)
    expected = mlp(2, 1, (8,))
    torch.random.set_rng_state(before)
    for got, want in zip(net.parameters(), expected.parameters()):
        assert torch.equal(got, want)
