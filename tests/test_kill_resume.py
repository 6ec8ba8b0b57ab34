"""kill -9 a training process after it has checkpointed; the same command finishes the run
on the curve an uninterrupted run draws, without starting over."""

import json
import os
import signal
import subprocess
import sys
import time

import pandas as pd

TRAIN = [
    sys.executable,
    "-m",
    "replicate",
    "train",
    "--algo",
    "sac",
    "--env",
    "Hopper-v5",
    "--steps",
    "1500",
    "--eval-interval",
    "300",
    "--eval-episodes",
    "1",
    "--seed",
    "2",
    "--checkpoint-interval",
    "100",
    "--set",
    "hidden_sizes=(16,16)",
    "--set",
    "batch_size=16",
    "--set",
    "learning_starts=100",
]


def train(store, **kwargs):
    env = dict(os.environ, MUJOCO_GL="disable")
    return subprocess.Popen(
        [*TRAIN, "--store", str(store)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        **kwargs,
    )


def the_run(store):
    runs = [p for p in store.iterdir() if not p.name.startswith(".")]
    assert len(runs) == 1
    return runs[0]


def test_kill_minus_nine_then_resume(tmp_path):
    reference_store, store = tmp_path / "reference", tmp_path / "killed"
    assert train(reference_store).wait(timeout=300) == 0

    process = train(store)
    deadline = time.time() + 240
    checkpoint = None
    while time.time() < deadline and process.poll() is None:
        # a run trains as a seed batch of one: the checkpoint is the batch's, the curve the run's
        found = list(store.glob(".batch-*/checkpoint.pt")) if store.exists() else []
        parts = list(store.glob(".partial-*/segments.json")) if store.exists() else []
        if found and parts and json.loads(parts[0].read_text())[-1]["wall_time_s"] > 0:
            curve = pd.read_csv(parts[0].parent / "curve.csv")
            if curve["step"].max() >= 600:  # well past a few checkpoints
                checkpoint = found[0]
                break
        time.sleep(0.2)
    assert checkpoint is not None, "the run never checkpointed before finishing"
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not any(p.name.startswith("sac__") for p in store.iterdir())  # nothing looks done

    assert train(store).wait(timeout=300) == 0
    run, reference = the_run(store), the_run(reference_store)
    assert run.name == reference.name
    parts = json.loads((run / "provenance.json").read_text())["segments"]
    assert len(parts) == 2 and parts[1]["resumed_from_step"] >= 300
    ours = pd.read_csv(run / "curve.csv")
    theirs = pd.read_csv(reference / "curve.csv")
    assert ours["step"].tolist() == theirs["step"].tolist()
    assert ours["returns"].tolist() == theirs["returns"].tolist()
    pd.testing.assert_series_equal(ours["train_return"], theirs["train_return"])
