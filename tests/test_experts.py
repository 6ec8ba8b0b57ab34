import json

import numpy as np
import pytest
import torch

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
    path = experts.train_expert(
        ENV, steps=300, root=root, eval_interval=100, checkpoint_interval=50
    )
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
    assert all(
        torch.equal(p.data, best[name].half().float())
        for name, p in policy.policy.state_dict().items()
        if p.is_floating_point()
    )

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
        experts.train_expert("dm_control/cartpole-swingup_sparse-v0", steps=10, root=expert_dir)


def test_missing_expert_is_a_clear_error(expert_dir):
    with pytest.raises(DemoError, match="no expert is available yet"):
        make_demos("Walker2d-v5")


def test_twin_q_expert_exports_a_policy_the_demonstrations_can_use(expert_dir):
    root = expert_dir / "work"
    env_id = "dm_control/cartpole-swingup-v0"  # its default expert trainer is the paper's SAC
    assert experts.expert_algo_for(env_id) == "sac"
    path = experts.train_expert(env_id, steps=200, root=root, eval_interval=100, algo="sac-twin-q")
    policy = experts.ExpertPolicy(env_id, path)
    assert policy.metadata["algo"] == "sac-twin-q"
    assert "--algo sac-twin-q" in policy.metadata["command"]  # not the env's default
    assert policy.metadata["command"].endswith("--device cpu")  # where it trained
    assert policy.metadata["device"] == "cpu"
    assert "initial_alpha" in policy.metadata["hyperparameters"]
    assert np.all(np.isfinite(policy(np.zeros(policy.policy.trunk[0].in_features))))
    with pytest.raises(HarnessError, match="expert run of sac-twin-q"):
        experts.train_expert(env_id, steps=200, root=root, algo="sac")
    with pytest.raises(HarnessError, match="not ppo"):
        experts.train_expert(env_id, steps=200, root=root, algo="ppo")


def test_a_seed_batch_exports_its_best_member(expert_dir):
    root = expert_dir / "work"
    path = experts.train_expert_batch(
        ENV, steps=300, seeds=[1, 2], root=root, eval_interval=100, device="cpu"
    )
    meta = experts.ExpertPolicy(ENV, path).metadata
    best = meta["batch_best_eval_return"]
    assert set(best) == {"1", "2"}
    assert meta["seed"] == int(max(best, key=best.get))
    assert meta["best_eval_return"] == pytest.approx(max(best.values()))
    assert meta["steps_trained"] == 300 and "--seeds 1,2" in meta["command"]
    member = torch.load(
        root / ENV / "batch" / f"seed-{meta['seed']}" / "best_policy.pt", weights_only=True
    )
    exported = torch.load(path, weights_only=True)["policy"]
    assert all(
        torch.equal(exported[name], t.half())
        for name, t in member["policy"].items()
        if t.is_floating_point()
    )
    for seed in (1, 2):  # every member kept its own curve and best policy
        progress = json.loads((root / ENV / "batch" / f"seed-{seed}" / "progress.json").read_text())
        assert [step for step, _ in progress["curve"]] == [0, 100, 200, 300]
        assert progress["best_mean_return"] == pytest.approx(best[str(seed)])


def test_a_time_limited_seed_batch_stops_and_keeps_what_it_evaluated(expert_dir):
    path = experts.train_expert_batch(
        ENV,
        steps=10_000,
        seeds=[1, 2],
        root=expert_dir / "w",
        eval_interval=100,
        device="cpu",
        time_limit_s=0,
    )
    meta = experts.ExpertPolicy(ENV, path).metadata
    assert meta["steps_trained"] == 0 and meta["best_step"] == 0  # stopped at its first step
    with pytest.raises(HarnessError, match="two or more distinct seeds"):
        experts.train_expert_batch(ENV, steps=100, seeds=[1, 1], root=expert_dir / "w")
