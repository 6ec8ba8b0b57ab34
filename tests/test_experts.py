import json

import numpy as np
import torch
import pytest

from replicate import experts
from replicate.demos import load_demos, make_demos, save_demos
from replicate.errors import DemoError, HarnessError

ENV = "Hopper-v5"


@pytest.fixture
def expert_dir(tmp_path, monkeypatch):
    """Send exported experts to a temporary directory instead of the package."""
    monkeypatch.setattr(experts, "expert_path", lambda env_id: tmp_path / "pkg" / f"{env_id}.pt")
    return tmp_path


def test_expert_trains_exports_and_makes_valid_demonstrations(expert_dir):
    root = expert_dir / "work"
    with pytest.raises(HarnessError, match="no expert training found"):
        experts.export_expert(ENV, root)
    path = experts.train_expert(ENV, steps=300, root=root, eval_interval=100,
                                checkpoint_interval=50)
    policy = experts.ExpertPolicy(ENV, path)
    meta = policy.metadata
    assert meta["steps_trained"] == 300 and meta["budget_steps"] == 300
    assert meta["best_eval_return"] == pytest.approx(max(r for _, r in meta["curve"]), abs=1e-3)
    assert not (root / "Hopper-v5" / "checkpoint.pt").exists()  # finished runs drop the buffer
    # the committed file holds half-precision weights; the policy acts as those weights do
    saved = torch.load(path, weights_only=True)
    assert meta["weights_dtype"] == "float16"
    assert all(t.dtype == torch.float16 for t in saved["policy"].values() if t.is_floating_point())
    best = torch.load(root / "Hopper-v5" / "best_policy.pt", weights_only=True)["policy"]
    assert all(torch.equal(p.data, best[name].half().float())
               for name, p in policy.policy.state_dict().items() if p.is_floating_point())

    demos = make_demos(ENV, n_pairs=50, seed=0)
    assert demos.metadata["expert_episodes"] >= 10
    assert demos.metadata["expert_algo"] == experts.expert_algo_for(ENV)
    first_action = policy(demos.observations[0])
    assert np.allclose(first_action, demos.actions[0], atol=1e-6)
    loaded = load_demos(save_demos(expert_dir / "demos.npz", demos), ENV)
    assert loaded.sha256 == demos.sha256 and loaded.has_transitions

    with pytest.raises(HarnessError, match="budget 300"):
        experts.train_expert(ENV, steps=600, root=root)
    progress = json.loads((root / "Hopper-v5" / "progress.json").read_text())
    assert progress["steps_done"] == 300


def test_sparse_task_takes_the_dense_twins_expert(expert_dir):
    with pytest.raises(HarnessError, match="takes its expert from"):
        experts.train_expert("dm_control/cartpole-swingup_sparse-v0", steps=10,
                             root=expert_dir)


def test_missing_expert_is_a_clear_error(expert_dir):
    with pytest.raises(DemoError, match="no expert is available yet"):
        make_demos("Walker2d-v5")


def test_twin_q_expert_exports_a_policy_the_demonstrations_can_use(expert_dir):
    root = expert_dir / "work"
    env_id = "Walker2d-v5"  # an env whose default expert trainer is the paper's SAC
    assert experts.expert_algo_for(env_id) == "sac"
    path = experts.train_expert(env_id, steps=200, root=root, eval_interval=100,
                                algo="sac-twin-q")
    policy = experts.ExpertPolicy(env_id, path)
    assert policy.metadata["algo"] == "sac-twin-q"
    assert "--algo sac-twin-q" in policy.metadata["command"]  # not the env's default
    assert policy.metadata["command"].endswith("--device cpu")  # where it trained
    assert policy.metadata["device"] == "cpu"
    assert "initial_alpha" in policy.metadata["hyperparameters"]
    assert np.all(np.isfinite(policy(np.zeros(17))))
    with pytest.raises(HarnessError, match="expert run of sac-twin-q"):
        experts.train_expert(env_id, steps=200, root=root, algo="sac")
    with pytest.raises(HarnessError, match="not ppo"):
        experts.train_expert(env_id, steps=200, root=root, algo="ppo")
