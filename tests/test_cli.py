import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from replicate.cli.main import main
from replicate.demos import default_demo_path

MC = "MountainCarContinuous-v0"
TINY_SET = [
    "--set",
    "hidden_sizes=(16,16)",
    "--set",
    "batch_size=16",
    "--set",
    "learning_starts=50",
]


def run_cli(args, capsys):
    code = main(args)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_one_line_error(code, err, *fragments):
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "fix:" in lines[0]
    for fragment in fragments:
        assert fragment in lines[0]


def store_entries(store):
    return sorted(p.name for p in store.iterdir()) if store.exists() else []


@pytest.mark.parametrize(
    "args, fragments",
    [
        (["--algo", "sac", "--env", "Hopper-v2", "--steps", "10"], ["unknown env", "Hopper-v5"]),
        (["--algo", "ddpg", "--env", MC, "--steps", "10"], ["unknown algorithm", "drl-eg", "sac"]),
        (["--algo", "sac", "--env", MC, "--steps", "-5"], ["step count must be positive"]),
        (
            ["--algo", "sac", "--env", MC, "--steps", "10", "--set", "gamma_typo=0.9"],
            ["unknown hyperparameter", "gamma_typo"],
        ),
    ],
)
def test_bad_input_is_one_line_non_zero_and_leaves_nothing(tmp_path, capsys, args, fragments):
    store = tmp_path / "store"
    code, _, err = run_cli(["train", *args, "--store", str(store)], capsys)
    assert_one_line_error(code, err, *fragments)
    assert store_entries(store) == []


def test_malformed_and_mismatched_demonstrations_are_refused(tmp_path, capsys):
    store = tmp_path / "store"
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"not a zip file at all")
    code, _, err = run_cli(
        [
            "train",
            "--algo",
            "drl-eg",
            "--env",
            MC,
            "--steps",
            "10",
            "--demos",
            str(broken),
            "--store",
            str(store),
        ],
        capsys,
    )
    assert_one_line_error(code, err, "malformed or truncated")

    wrong_dims = tmp_path / "wrong.npz"
    shutil.copy(default_demo_path(MC), wrong_dims)
    with np.load(wrong_dims) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["actions"] = np.concatenate([arrays["actions"], arrays["actions"]], axis=1)
    np.savez(wrong_dims, **arrays)
    code, _, err = run_cli(
        [
            "train",
            "--algo",
            "drl-eg",
            "--env",
            MC,
            "--steps",
            "10",
            "--demos",
            str(wrong_dims),
            "--store",
            str(store),
        ],
        capsys,
    )
    assert_one_line_error(code, err, "dims 2/2", "2/1")

    code, _, err = run_cli(
        [
            "train",
            "--algo",
            "drl-eg",
            "--env",
            MC,
            "--steps",
            "10",
            "--demos",
            str(tmp_path / "absent.npz"),
            "--store",
            str(store),
        ],
        capsys,
    )
    assert_one_line_error(code, err, "not found")
    assert store_entries(store) == []


def test_train_writes_a_complete_run_directory_and_skips_it_the_second_time(tmp_path, capsys):
    store = tmp_path / "store"
    args = [
        "train",
        "--algo",
        "drl-eg",
        "--env",
        MC,
        "--steps",
        "120",
        "--seed",
        "2",
        "--eval-interval",
        "60",
        "--eval-episodes",
        "1",
        *TINY_SET,
        "--store",
        str(store),
    ]
    code, out, _ = run_cli(args, capsys)
    assert code == 0
    (run_dir,) = [p for p in store.iterdir()]
    assert run_dir.name.startswith("drl-eg__MountainCarContinuous-v0__s2__")
    spec = json.loads((run_dir / "spec.json").read_text())
    prov = json.loads((run_dir / "provenance.json").read_text())
    assert spec["hyperparameters"]["hidden_sizes"] == [16, 16]
    assert spec["demos"]["n_pairs"] == 1000 and len(spec["demos"]["sha256"]) == 64
    assert prov["seed"] == 2 and prov["wall_time_s"] > 0 and prov["versions"]["torch"]
    assert prov["git_revision"]
    assert prov["machine"]["cpu_model"]  # CPU curves repeat bit for bit on the same CPU kind
    assert prov["machine"]["flushes_denormals"] is True  # x86: every trainer flushes them
    curve = (run_dir / "curve.csv").read_text().splitlines()
    assert curve[0].startswith("step,return_mean") and len(curve) == 1 + 3  # steps 0, 60, 120
    mtime = (run_dir / "provenance.json").stat().st_mtime
    code, _, _ = run_cli(args, capsys)
    assert code == 0 and (run_dir / "provenance.json").stat().st_mtime == mtime


def test_train_seeds_in_a_batch_give_each_seed_the_curve_it_draws_alone(tmp_path, capsys):
    import pandas as pd

    common = ["train", "--algo", "sac", "--env", "Hopper-v5", "--steps", "240"]
    common += ["--eval-interval", "120", "--eval-episodes", "1", *TINY_SET]
    together, alone = tmp_path / "together", tmp_path / "alone"
    batch = ["--seed", "3", "--seeds", "2", "--batch", "2", "--workers", "1"]
    code, out, _ = run_cli([*common, *batch, "--store", str(together)], capsys)
    assert code == 0 and out.count("final return") == 2
    assert run_cli([*common, "--seed", "4", "--store", str(alone)], capsys)[0] == 0
    (seed4,) = [p for p in together.iterdir() if "__s4__" in p.name]
    (single,) = [p for p in alone.iterdir() if not p.name.startswith(".")]
    assert seed4.name == single.name  # one address: batching is not part of a run's spec
    returns = [pd.read_csv(d / "curve.csv")["return_mean"] for d in (seed4, single)]
    np.testing.assert_allclose(returns[0], returns[1], rtol=1e-6)


def test_a_crashing_run_leaves_no_directory(tmp_path, capsys, monkeypatch):
    import baselines.training_loop

    def explode(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(baselines.training_loop, "evaluate_members", explode)
    store = tmp_path / "store"
    with pytest.raises(RuntimeError, match="boom"):
        main(["train", "--algo", "sac", "--env", MC, "--steps", "10", "--store", str(store)])
    assert store_entries(store) == []


def test_help_explains_every_option():
    result = subprocess.run(
        [sys.executable, "-m", "replicate", "train", "--help"],
        capture_output=True,
        text=True,
        check=True,
    )
    for option in (
        "--algo",
        "--env",
        "--steps",
        "--seed",
        "--eval-interval",
        "--eval-episodes",
        "--demos",
        "--set",
        "--store",
    ):
        assert option in result.stdout
    assert "environment steps" in result.stdout


def test_listing_commands(capsys):
    code, out, _ = run_cli(["algos"], capsys)
    assert code == 0 and "drl-eg" in out and "guide_threshold" in out
    code, out, _ = run_cli(["envs"], capsys)
    assert code == 0 and "Ant-v2 (111/8)" in out


def test_the_command_line_knows_every_profile_and_keeps_smoke_runs_apart(monkeypatch):
    from replicate.cli.main import default_store
    from replicate.grids.options import PROFILE_NAMES
    from replicate.grids.profiles import PROFILES

    assert PROFILE_NAMES == tuple(PROFILES)
    monkeypatch.delenv("REPLICATE_STORE", raising=False)
    assert str(default_store("smoke")) == "runs-smoke" and str(default_store("quick")) == "runs"
    monkeypatch.setenv("REPLICATE_STORE", "/elsewhere")
    assert str(default_store("smoke")) == "/elsewhere"


@pytest.mark.parametrize(
    "command",
    [
        "fig3",
        "fig4",
        "ablate-threshold",
        "compare-rlfd",
        "report",
        "train",
        "expert",
        "carry",
        "confirm",
    ],
)
def test_help_describes_every_profile_and_states_each_default_once(command, capsys, monkeypatch):
    from replicate.grids.profiles import PROFILES

    monkeypatch.setenv("COLUMNS", "100")
    with pytest.raises(SystemExit):
        main([command, "--help"])
    out = capsys.readouterr().out
    flat = " ".join(out.split())
    assert "(default: None)" not in flat and "(default: False)" not in flat
    options = flat.split(" --")[1:]  # one piece per option, from its flag to the next
    for option in options:
        assert option.lower().count("default") <= 1, option
    if "--profile" in out:
        for name, profile in PROFILES.items():
            assert f"{name}: {' '.join(profile.summary.split())}" in flat


def test_expert_without_env_trains_every_expert_env_in_turn(monkeypatch):
    from replicate.cli import main as cli
    from replicate.cli import runs as cli_runs
    from replicate.experts import EXPERT_ENVS

    seen = []
    monkeypatch.setattr(cli_runs, "_one_expert", lambda args: seen.append(args.env))
    assert cli.main(["expert", "--export-only"]) == 0
    assert seen == list(EXPERT_ENVS)
    seen.clear()
    assert cli.main(["expert", "--env", "Hopper-v5", "--export-only"]) == 0
    assert seen == ["Hopper-v5"]


@pytest.mark.parametrize("workers", ["-1", "0", "two"])
def test_a_worker_count_below_one_is_refused_in_one_line(workers, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["fig3", "--workers", workers, "--dry-run"])
    assert stop.value.code == 2
    assert "argument --workers" in capsys.readouterr().err.strip().splitlines()[-1]
