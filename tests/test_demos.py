import json
import shutil

import numpy as np
import pytest

from replicate.demos import (
    Demonstrations,
    default_demo_path,
    load_demos,
    mountaincar_rule,
    save_demos,
)
from replicate.errors import DemoError
from replicate.experts import make_demos

MC = "MountainCarContinuous-v0"


def test_committed_mountaincar_demos_follow_the_papers_rule():
    demos = load_demos(default_demo_path(MC), MC)
    assert demos.observations.shape == (1000, 2) and demos.actions.shape == (1000, 1)
    expected = np.where(demos.observations[:, 1] < 0, -0.5, 0.5)
    np.testing.assert_array_equal(demos.actions[:, 0], expected)
    meta = demos.metadata
    for key in (
        "env_id",
        "env_version",
        "n_pairs",
        "expert",
        "expert_return_mean",
        "expert_return_std",
        "seed",
        "command",
        "content_sha256",
        "format_version",
    ):
        assert key in meta
    assert meta["expert_return_mean"] > 90  # the rule reaches the mountaintop every episode
    assert all(r > 90 for r in meta["expert_returns"])


def test_regeneration_is_deterministic_and_matches_the_committed_file():
    committed = load_demos(default_demo_path(MC), MC)
    again = make_demos(MC, n_pairs=1000, seed=committed.metadata["seed"])
    assert again.sha256 == committed.sha256


def test_rule_action():
    assert mountaincar_rule(np.array([-0.5, -0.01]))[0] == -0.5
    assert mountaincar_rule(np.array([-0.5, 0.0]))[0] == 0.5


@pytest.fixture
def demo_file(tmp_path):
    path = tmp_path / "mc.npz"
    shutil.copy(default_demo_path(MC), path)
    return path


def rewrite(path, **changes):
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update(changes)
    np.savez(path, **arrays)


def expect_refusal(path, env_id, fragment):
    with pytest.raises(DemoError) as info:
        load_demos(path, env_id)
    message = str(info.value)
    assert fragment in message and "\n" not in message and "fix:" in message


def test_wrong_env_is_refused(demo_file):
    expect_refusal(demo_file, "Hopper-v5", "is for env 'MountainCarContinuous-v0'")


def test_wrong_dimensions_are_refused(demo_file):
    with np.load(demo_file) as data:
        obs = data["observations"]
    rewrite(demo_file, observations=np.concatenate([obs, obs[:, :1]], axis=1))
    expect_refusal(demo_file, MC, "obs/action dims 3/1")


def test_nan_is_refused(demo_file):
    with np.load(demo_file) as data:
        obs = data["observations"].copy()
    obs[10, 0] = np.nan
    rewrite(demo_file, observations=obs)
    expect_refusal(demo_file, MC, "NaN or inf")


def test_tampered_content_fails_the_hash(demo_file):
    with np.load(demo_file) as data:
        actions = data["actions"].copy()
    actions[0, 0] = 0.25
    rewrite(demo_file, actions=actions)
    expect_refusal(demo_file, MC, "content hash")


def test_truncated_file_is_refused(demo_file):
    payload = demo_file.read_bytes()
    demo_file.write_bytes(payload[: len(payload) // 2])
    expect_refusal(demo_file, MC, "malformed or truncated")


def test_missing_file_and_missing_entries_are_refused(tmp_path, demo_file):
    expect_refusal(tmp_path / "absent.npz", MC, "not found")
    with np.load(demo_file) as data:
        np.savez(demo_file, observations=data["observations"], actions=data["actions"])
    expect_refusal(demo_file, MC, "lacks ['metadata']")


def test_pair_count_mismatch_is_refused(demo_file):
    with np.load(demo_file) as data:
        meta = json.loads(str(data["metadata"]))
    meta["n_pairs"] = 999
    rewrite(demo_file, metadata=np.array(json.dumps(meta)))
    expect_refusal(demo_file, MC, "declares 999 pairs")


def test_save_then_load_round_trip(tmp_path):
    demos = make_demos(MC, n_pairs=50, seed=1)
    path = save_demos(tmp_path / "d.npz", demos)
    loaded = load_demos(path, MC)
    assert isinstance(loaded, Demonstrations) and len(loaded.observations) == 50
    np.testing.assert_array_equal(loaded.actions, demos.actions)
