"""Carried checkpoints: an interrupted run or seed batch packed without its replay, moved to
a store that has nothing else of it, resumes there and ends on the uninterrupted curve."""

import json
import shutil

import pytest
import torch

from replicate.cli.main import main
from replicate.store import carry
from replicate.store.runner import execute, execute_batch, prepare
from replicate.store.spec import RunSpec
from tests.helpers import TINY

HOPPER = "Hopper-v5"


class _Stop(KeyboardInterrupt):
    """Raised from the progress callback: the process is interrupted, the checkpoint kept."""


def _stop_after(calls: int):
    seen = [0]

    def on_steps(n: int) -> None:
        seen[0] += 1
        if seen[0] == calls:
            raise _Stop

    return on_steps


def _curves(store):
    """Each finished run's curve without its wall-time column."""
    return {
        p.name: [line.rsplit(",", 1)[0] for line in (p / "curve.csv").read_text().splitlines()]
        for p in sorted(store.iterdir())
        if (p / "provenance.json").is_file()
    }


def _batch_specs():
    return [prepare(RunSpec("drl-eg", HOPPER, seed, 700, 350, 1, dict(TINY))) for seed in (0, 1)]


def test_a_carried_batch_resumes_in_another_store_on_the_uninterrupted_curves(
    tmp_path, monkeypatch
):
    whole, first, second = tmp_path / "whole", tmp_path / "first", tmp_path / "second"
    execute_batch(_batch_specs(), whole, device="cpu", checkpoint_interval=200)

    with pytest.raises(_Stop):  # stopped at step 500, after the checkpoint at 400
        execute_batch(
            _batch_specs(), first, device="cpu", checkpoint_interval=200, on_steps=_stop_after(500)
        )
    (checkpoint,) = first.glob(".batch-*/checkpoint.pt")
    packed, skipped = carry.pack_all(first)
    assert skipped == [] and [p.step for p in packed] == [400] and packed[0].members == 2
    state = carry.carry_root(first) / packed[0].name
    assert packed[0].bytes < checkpoint.stat().st_size / 2  # the replay stayed behind

    shutil.copytree(carry.carry_root(first), carry.carry_root(second))  # another machine
    outcome = execute_batch(_batch_specs(), second, device="cpu", checkpoint_interval=200)
    assert len(outcome.runs) == 2 and not outcome.failed
    assert _curves(second) == _curves(whole)
    for run in outcome.runs:
        parts = json.loads((run.path / "segments.json").read_text())
        assert [s["resumed_from_step"] for s in parts] == [0, 400]
        assert parts[0]["carried"]["replay"] == "rebuilt bit for bit"
    assert state.name not in {p.name for p in carry.carry_root(second).iterdir()}  # done

    # where the replay rebuilds differently and the user accepts it, the batch resumes too
    third = tmp_path / "third"
    shutil.copytree(carry.carry_root(first), carry.carry_root(third))
    manifest_path = carry.carry_root(third) / packed[0].name / carry.MANIFEST_FILE
    manifest = json.loads(manifest_path.read_text())
    manifest_path.write_text(json.dumps({**manifest, "replay_sha256": "0" * 64}))
    monkeypatch.setenv(carry.ACCEPT_REBUILT, "1")
    execute_batch(_batch_specs(), third, device="cpu", checkpoint_interval=200)
    assert _curves(third) == _curves(whole)  # the envs step alike here, after all


def test_a_carried_single_run_resumes_on_the_uninterrupted_curve(tmp_path):
    spec = RunSpec("sac", HOPPER, 3, 700, 350, 1, dict(TINY))
    whole, first, second = tmp_path / "whole", tmp_path / "first", tmp_path / "second"
    execute(prepare(spec), whole, device="cpu", checkpoint_interval=150)
    with pytest.raises(_Stop):
        execute(
            prepare(spec), first, device="cpu", checkpoint_interval=150, on_steps=_stop_after(600)
        )
    assert main(["carry", "--store", str(first)]) == 0
    (manifest,) = carry.listing(first)
    # a single run of the SAC family is a seed batch of one
    assert manifest["members"] == [prepare(spec).run_id] and 150 <= manifest["step"] < 600
    shutil.copytree(carry.carry_root(first), carry.carry_root(second))
    execute(prepare(spec), second, device="cpu", checkpoint_interval=150)
    assert _curves(second) == _curves(whole)
    assert carry.listing(second) == []


def test_a_carried_replay_that_does_not_rebuild_is_refused_and_kept(tmp_path, monkeypatch):
    spec = RunSpec("sac", HOPPER, 4, 500, 250, 1, dict(TINY))
    with pytest.raises(_Stop):
        execute(
            prepare(spec),
            tmp_path,
            device="cpu",
            checkpoint_interval=100,
            on_steps=_stop_after(400),
        )
    (packed,), _ = carry.pack_all(tmp_path)
    shutil.rmtree(tmp_path / f".{packed.name}")
    manifest_path = carry.carry_root(tmp_path) / packed.name / carry.MANIFEST_FILE
    manifest = json.loads(manifest_path.read_text())
    manifest["replay_sha256"] = "0" * 64  # as if the envs stepped differently here
    manifest_path.write_text(json.dumps(manifest))
    with pytest.raises(carry.CarryError, match="did not rebuild its replay on this machine"):
        execute(prepare(spec), tmp_path, device="cpu")
    assert carry.listing(tmp_path)  # still carried, for a machine where it rebuilds
    monkeypatch.setenv(carry.ACCEPT_REBUILT, "1")  # the user takes the replay as rebuilt
    run = execute(prepare(spec), tmp_path, device="cpu")
    assert "accepted" in run.provenance["segments"][0]["carried"]["replay"]


def test_a_wrapped_replay_is_not_carried(tmp_path, capsys):
    spec = RunSpec("sac", HOPPER, 5, 500, 250, 1, {**TINY, "buffer_size": 150})
    with pytest.raises(_Stop):
        execute(
            prepare(spec),
            tmp_path,
            device="cpu",
            checkpoint_interval=100,
            on_steps=_stop_after(400),
        )
    assert (
        torch.load(next(tmp_path.glob(".batch-*/checkpoint.pt")), weights_only=False)["step"] > 150
    )
    assert main(["carry", "--store", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "not carried" in out and "wrapped around" in out
    assert carry.listing(tmp_path) == []


def test_a_carried_batch_is_planned_as_the_batch_it_was_whatever_batch_says(tmp_path):
    from replicate.grids.planning import plan_batches

    runs = [prepare(RunSpec("sac", HOPPER, seed, 700, 350, 1, dict(TINY))) for seed in range(4)]
    entry = carry.carry_root(tmp_path) / "batch-x"
    entry.mkdir(parents=True)
    members = [runs[3].run_id, runs[1].run_id]
    (entry / carry.MANIFEST_FILE).write_text(
        json.dumps(
            {
                "format": carry.FORMAT,
                "kind": "batch",
                "name": "batch-x",
                "step": 350,
                "members": members,
                "packed_utc": "then",
                "cpu_model": "x",
            }
        )
    )
    for batch in (None, 1, 3):
        tasks = plan_batches(runs, batch, tmp_path)
        assert [p.run_id for p in tasks[0]] == members
        rest = [p.run_id for t in tasks[1:] for p in (t if isinstance(t, list) else [t])]
        assert sorted(rest) == sorted([runs[0].run_id, runs[2].run_id])
    assert plan_batches(runs[:2], 3, tmp_path)[0] == runs[:2]  # a member is done: not carried


def test_estimates_count_only_the_steps_left_after_the_carried_step(tmp_path, capsys):
    from replicate.grids.planning import estimate_minutes, print_plan

    runs = [prepare(RunSpec("sac", HOPPER, seed, 6000, 3000, 1, dict(TINY))) for seed in range(3)]
    whole = estimate_minutes([runs[:2], runs[2]], tmp_path, workers=1)
    entry = carry.carry_root(tmp_path) / "batch-z"
    entry.mkdir(parents=True)
    (entry / carry.MANIFEST_FILE).write_text(
        json.dumps(
            {
                "format": carry.FORMAT,
                "kind": "batch",
                "name": "batch-z",
                "step": 4500,
                "members": [runs[0].run_id, runs[1].run_id],
                "packed_utc": "then",
                "cpu_model": "x",
            }
        )
    )
    # the batch has 1,500 of its 6,000 steps per member left; the third run all 6,000
    assert estimate_minutes([runs[:2], runs[2]], tmp_path, workers=1) == pytest.approx(
        whole * (2 * 1500 + 6000) / 18000
    )
    # a carry resumes only whole, and on Ray a carried batch starts over
    assert estimate_minutes([runs[0], runs[2]], tmp_path, workers=1) == pytest.approx(whole * 2 / 3)
    assert estimate_minutes(runs, tmp_path, workers=1, carried_batches=False) == whole
    print_plan(runs, runs, tmp_path, workers=1)
    out = capsys.readouterr().out
    assert "18,000 env steps  " in out and "(9,000 of them carried)" in out
    assert "total 18,000 env steps (9,000 to train, the rest carried)" in out


def test_a_report_names_the_step_a_missing_run_is_carried_at(tmp_path):
    from replicate.grids.train import absent_cells

    specs = [RunSpec("sac", HOPPER, seed, 700, 350, 1, dict(TINY)) for seed in (0, 1)]
    entry = carry.carry_root(tmp_path) / "batch-y"
    entry.mkdir(parents=True)
    (entry / carry.MANIFEST_FILE).write_text(
        json.dumps(
            {
                "format": carry.FORMAT,
                "kind": "batch",
                "name": "batch-y",
                "step": 1234,
                "members": [prepare(specs[1]).run_id],
                "packed_utc": "then",
                "cpu_model": "x",
            }
        )
    )
    ((env_id, algo, why),) = absent_cells(specs, "nox -s x", tmp_path)
    assert (env_id, algo) == (HOPPER, "sac")
    assert "seeds 0, 1 not in the store yet" in why and "seed 1 at step 1,234" in why
    assert "carried" not in absent_cells(specs, "nox -s x")[0][2]  # no store, no carry


def test_a_carry_whose_runs_landed_is_pruned_and_an_older_local_checkpoint_gives_way(tmp_path):
    spec = RunSpec("sac", HOPPER, 6, 700, 350, 1, dict(TINY))
    first, second = tmp_path / "first", tmp_path / "second"
    with pytest.raises(_Stop):
        execute(
            prepare(spec), first, device="cpu", checkpoint_interval=100, on_steps=_stop_after(250)
        )
    shutil.copytree(first, second)  # the same store on two machines
    with pytest.raises(_Stop):  # one trains on and packs again, further on
        execute(
            prepare(spec), second, device="cpu", checkpoint_interval=100, on_steps=_stop_after(300)
        )
    (packed,), _ = carry.pack_all(second)
    local = first / f".{packed.name}" / carry.CHECKPOINT_FILE
    assert torch.load(local, weights_only=False)["step"] < packed.step
    shutil.copytree(carry.carry_root(second), carry.carry_root(first))
    assert carry.should_unpack(first, packed.name, local)  # the carried one is further on
    again, skipped = carry.pack_all(first)  # nor does packing put the older one over it
    assert again == [] and "already" in skipped[0]
    assert carry.listing(first)[0]["step"] == packed.step
    run = execute(prepare(spec), first, device="cpu")
    assert run.provenance["segments"][-2]["carried"]["step"] == packed.step
    assert carry.listing(first) == []  # discarded when the run landed
    shutil.copytree(carry.carry_root(second), carry.carry_root(first), dirs_exist_ok=True)
    assert carry.prune(first) == [packed.name] and carry.listing(first) == []


def test_carry_packs_several_checkpoints_on_several_workers(tmp_path, capsys):
    for seed in (7, 8):
        with pytest.raises(_Stop):
            execute(
                prepare(RunSpec("sac", HOPPER, seed, 500, 250, 1, dict(TINY))),
                tmp_path,
                device="cpu",
                checkpoint_interval=100,
                on_steps=_stop_after(300),
            )
    assert main(["carry", "--store", str(tmp_path), "--workers", "0"]) == 2
    assert "--workers must be at least 1" in capsys.readouterr().err
    assert main(["carry", "--store", str(tmp_path), "--workers", "2"]) == 0
    assert sorted(m["seeds"][0] for m in carry.listing(tmp_path)) == [7, 8]


def test_a_kill_mid_swap_leaves_the_last_carried_version_found(tmp_path):
    root = carry.carry_root(tmp_path)
    for name in (".run-a.old", ".run-b.packing"):  # the swap's two sides, as a kill leaves them
        (root / name).mkdir(parents=True)
        (root / name / carry.MANIFEST_FILE).write_text(
            json.dumps(
                {
                    "format": carry.FORMAT,
                    "kind": "run",
                    "name": name[1:6],
                    "step": 1,
                    "members": [name[1:6]],
                }
            )
        )
    assert [m["name"] for m in carry.listing(tmp_path)] == ["run-a"]  # put back; b unfinished
    assert carry.carried(tmp_path, "run-a") is not None and carry.carried(tmp_path, "run-b") is None


def test_the_runner_and_the_scheduler_reach_the_carry_only_through_checkpoint_places():
    import ast
    from pathlib import Path

    import replicate

    core = (
        "store/runner",
        "grids/experiments",
        "grids/planning",
        "grids/train",
        "grids/ray_executor",
    )
    for name in core:
        tree = ast.parse((Path(replicate.__file__).parent / f"{name}.py").read_text())
        imported = {
            (node.module or "") + "." + alias.name
            for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom)
            for alias in node.names
        } | {
            alias.name
            for node in ast.walk(tree)
            if isinstance(node, ast.Import)
            for alias in node.names
        }
        assert not {i for i in imported if i.startswith("replicate.store.carry")}, name


def test_a_checkpoint_place_is_asked_before_a_batch_trains_and_told_when_it_lands(
    tmp_path, monkeypatch
):
    from replicate.grids.planning import estimate_minutes
    from replicate.store import checkpoint_places
    from replicate.store.checkpoint_places import KeptCheckpoint

    class Place:
        def __init__(self):
            self.fetched, self.landed_names = [], []

        def kept(self, store):
            return [KeptCheckpoint("batch-elsewhere", ("run-a", "run-b"), 300, tmp_path, "kept")]

        def fetch(self, store, name, checkpoint):
            self.fetched.append((name, checkpoint.name))

        def landed(self, store, names):
            self.landed_names.extend(names)

        def tidy(self, store):
            pass

    place = Place()
    monkeypatch.setattr(checkpoint_places, "places", lambda: [place])
    assert checkpoint_places.resumable_steps(tmp_path, {"run-a", "run-b", "run-c"}) == {
        "run-a": 300,
        "run-b": 300,
    }
    assert checkpoint_places.resumable_steps(tmp_path, {"run-a"}) == {}  # only whole
    (prepared,) = [prepare(RunSpec("sac", HOPPER, 0, 200, 100, 1, dict(TINY)))]
    assert estimate_minutes([prepared], tmp_path, 1, {("sac", HOPPER): 1.0}) == 200 / 60
    run = execute(prepared, tmp_path)
    ((name, file),) = place.fetched
    assert name.startswith("batch-") and file == "checkpoint.pt"
    assert place.landed_names == [name, run.path.name]
