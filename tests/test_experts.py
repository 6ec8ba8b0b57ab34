import numpy as np
import pytest
import torch

from replicate import experts
from replicate.demos import load_demos, save_demos
from replicate.errors import DemoError, HarnessError
from replicate.store.runs import completed_runs

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
    # an expert is an ordinary run of its store, with its best policy beside its curve
    (run,) = completed_runs(root / ENV)
    assert run.path.name == meta["run_id"] and run.spec["hyperparameters"]["keep_best_policy"]
    assert not list((root / ENV).rglob("checkpoint.pt"))  # finished runs drop the buffer
    # the committed file holds half-precision weights; the policy acts as those weights do
    saved = torch.load(path, weights_only=True)
    assert meta["weights_dtype"] == "float16"
    assert all(t.dtype == torch.float16 for t in saved["policy"].values() if t.is_floating_point())
    best = torch.load(run.path / "best_policy.pt", weights_only=True)["policy"]
    assert all(
        torch.equal(p.data, best[name].half().float())
        for name, p in policy.policy.state_dict().items()
        if p.is_floating_point()
    )

    demos = experts.make_demos(ENV, n_pairs=50, seed=0)
    assert demos.metadata["expert_episodes"] >= 10
    assert demos.metadata["expert_algo"] == experts.expert_algo_for(ENV)
    first_action = policy(demos.observations[0])
    assert np.allclose(first_action, demos.actions[0], atol=1e-6)
    loaded = load_demos(save_demos(expert_dir / "demos.npz", demos), ENV)
    assert loaded.sha256 == demos.sha256 and loaded.has_transitions

    # the same request again finds its run in the store and trains nothing
    again = experts.train_expert(ENV, steps=300, root=root, eval_interval=100)
    assert experts.ExpertPolicy(ENV, again).metadata["wall_time_s"] == meta["wall_time_s"]


def test_sparse_task_takes_the_dense_twins_expert(expert_dir):
    with pytest.raises(HarnessError, match="takes its expert from"):
        experts.train_expert("dm_control/cartpole-swingup_sparse-v0", steps=10, root=expert_dir)


def test_missing_expert_is_a_clear_error(expert_dir):
    with pytest.raises(DemoError, match="no expert is available yet"):
        experts.make_demos("Walker2d-v5")


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
    with pytest.raises(HarnessError, match="not ppo"):
        experts.train_expert(env_id, steps=200, root=root, algo="ppo")


def test_a_seed_batch_exports_its_best_member(expert_dir):
    root = expert_dir / "work"
    path = experts.train_expert(
        ENV, steps=300, seeds=[1, 2], root=root, eval_interval=100, device="cpu"
    )
    meta = experts.ExpertPolicy(ENV, path).metadata
    best = meta["batch_best_eval_return"]
    assert set(best) == {"1", "2"}
    assert meta["seed"] == int(max(best, key=best.get))
    assert meta["best_eval_return"] == pytest.approx(max(best.values()))
    assert meta["steps_trained"] == 300 and "--seeds 1,2" in meta["command"]
    member = torch.load(root / ENV / meta["run_id"] / "best_policy.pt", weights_only=True)
    exported = torch.load(path, weights_only=True)["policy"]
    assert all(
        torch.equal(exported[name], t.half())
        for name, t in member["policy"].items()
        if t.is_floating_point()
    )
    runs = completed_runs(root / ENV)  # every member kept its own curve and best policy
    assert sorted(run.spec["seed"] for run in runs) == [1, 2]
    for run in runs:
        assert run.curve["step"].tolist() == [0, 100, 200, 300]
        assert run.curve["return_mean"].max() == pytest.approx(
            best[str(run.spec["seed"])], rel=1e-5
        )
        assert run.provenance["batch"]["size"] == 2


def test_a_time_limited_expert_stops_exports_what_it_evaluated_and_resumes(expert_dir):
    root = expert_dir / "w"
    path = experts.train_expert(
        ENV, steps=300, seeds=[1, 2], root=root, eval_interval=100, device="cpu", time_limit_s=0
    )
    meta = experts.ExpertPolicy(ENV, path).metadata
    assert meta["steps_trained"] == 0 and meta["best_step"] == 0  # stopped at its first step
    assert "--minutes 0" not in meta["command"]
    assert not completed_runs(root / ENV)
    # the same command without the limit goes on from the checkpoint
    path = experts.train_expert(ENV, steps=300, seeds=[1, 2], root=root, eval_interval=100)
    assert experts.ExpertPolicy(ENV, path).metadata["steps_trained"] == 300
    assert len(completed_runs(root / ENV)) == 2
    with pytest.raises(HarnessError, match="must be distinct"):
        experts.train_expert(ENV, steps=100, seeds=[1, 1], root=root)
