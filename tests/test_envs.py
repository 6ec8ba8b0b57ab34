import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from envs import ENV_SPECS, PAPER_ENV_IDS, UnknownEnvError, env_spec, make_env


# the checker is run on the adapter on purpose: the adapter is what the harness trains on
@pytest.mark.filterwarnings("ignore:.*is different from the unwrapped version")
@pytest.mark.parametrize("env_id", list(ENV_SPECS))
def test_adapter_passes_gymnasium_checker_and_matches_spec_table(env_id):
    env = make_env(env_id, seed=0)
    check_env(env, skip_render_check=True)
    spec = ENV_SPECS[env_id]
    assert env.observation_space.shape == (spec.obs_dim,)
    assert env.observation_space.dtype == np.float32
    assert env.action_space.shape == (spec.act_dim,)
    assert env.action_space.dtype == np.float32
    obs, _ = env.reset(seed=3)
    assert obs.dtype == np.float32 and obs.shape == (spec.obs_dim,)
    obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
    assert obs.dtype == np.float32 and isinstance(reward, float)
    assert isinstance(terminated, bool) and isinstance(truncated, bool)
    env.close()


def test_paper_envs_and_dm_control_tasks_are_in_the_table():
    assert PAPER_ENV_IDS == (
        "MountainCarContinuous-v0",
        "Hopper-v5",
        "Walker2d-v5",
        "HalfCheetah-v5",
        "Ant-v5",
    )
    for task in (
        "dm_control/cartpole-swingup_sparse-v0",
        "dm_control/ball_in_cup-catch-v0",
        "dm_control/walker-walk-v0",
    ):
        assert ENV_SPECS[task].suite == "dm_control"
    assert ENV_SPECS["Ant-v5"].paper_obs_dim == 111 and ENV_SPECS["Ant-v5"].obs_dim == 105


def test_unknown_env_lists_the_known_ones():
    with pytest.raises(UnknownEnvError) as info:
        make_env("Hopper-v2")
    message = str(info.value)
    assert (
        "Hopper-v2" in message and "Hopper-v5" in message and "dm_control/walker-walk-v0" in message
    )
    with pytest.raises(UnknownEnvError):
        env_spec("nope")


@pytest.mark.parametrize("env_id", ["MountainCarContinuous-v0", "dm_control/cartpole-swingup-v0"])
def test_time_limit_is_truncation_not_termination(env_id):
    env = make_env(env_id, seed=0)
    env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    for step in range(1, ENV_SPECS[env_id].max_episode_steps + 1):
        _, _, terminated, truncated, _ = env.step(zero)
        if terminated or truncated:
            break
    assert step == ENV_SPECS[env_id].max_episode_steps
    assert truncated and not terminated


def test_same_seed_same_start_state():
    a, _ = make_env("Hopper-v5", seed=7).reset(seed=7)
    b, _ = make_env("Hopper-v5", seed=7).reset(seed=7)
    c, _ = make_env("Hopper-v5", seed=8).reset(seed=8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
