"""--time-limit: a run stopped at its deadline keeps a checkpoint and resumes onto the
uninterrupted curve; a grid past its limit stops with one line and exit 75; a bad limit is
one line, exit 2, and trains nothing."""

from __future__ import annotations

import json
import time

import pandas as pd
import pytest

from baselines.common.checkpoint import TimeLimitReached
from replicate.cli.main import main, parse_time_limit
from replicate.errors import HarnessError
from replicate.grids import experiments
from replicate.grids.options import TIME_LIMIT_EXIT
from replicate.store.run_recorder import EARLIER_SEGMENTS_FILE
from replicate.store.runner import (
    CHECKPOINT_FILE,
    SEGMENTS_FILE,
    batch_id,
    execute,
    execute_batch,
    partial_directory,
    prepare,
)
from replicate.store.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY

FIGURE_COMMANDS = ("fig3", "fig4", "ablate-threshold", "compare-rlfd")


def curve_without_wall_time(run_dir) -> pd.DataFrame:
    return pd.read_csv(run_dir / "curve.csv").drop(columns="wall_s")


@pytest.mark.parametrize(
    "text, seconds",
    [
        ("90m", 5400),
        ("2h", 7200),
        ("1h30m", 5400),
        ("1h 30m", 5400),
        ("45s", 45),
        ("5400", 5400),
        ("1.5h", 5400),
        ("0.25", 0.25),
        (" 2H ", 7200),
    ],
)
def test_time_limits_read_as_seconds(text, seconds):
    assert parse_time_limit(text) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["0", "0m", "-5m", "-1", "abc", "2x", "h", "", "1h-5m", "2h30"])
def test_unreadable_zero_or_negative_limits_are_refused(text):
    with pytest.raises(HarnessError):
        parse_time_limit(text)


@pytest.mark.parametrize(
    "command, limit",
    [
        ("fig3", "0"),
        ("fig3", "-5m"),
        ("fig3", "soon"),
        ("fig4", "-1"),
        ("ablate-threshold", "0s"),
        ("compare-rlfd", "-2h"),
    ],
)
def test_a_bad_limit_is_one_line_exit_2_and_trains_nothing(tmp_path, capsys, command, limit):
    store = tmp_path / "store"
    code = main(
        [
            command,
            "--profile",
            "smoke",
            "--store",
            str(store),
            "--out",
            str(tmp_path / "out"),
            "--time-limit",
            limit,
        ]
    )
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2
    assert len(lines) == 1 and lines[0].startswith("error: --time-limit")
    assert not store.exists() and not (tmp_path / "out").exists()


def test_every_figure_command_takes_the_limit(capsys):
    for command in FIGURE_COMMANDS:
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "--time-limit DURATION" in capsys.readouterr().out


# the off-policy trainer (a run is a batch of one) and the two loops of their own
@pytest.mark.parametrize("algo", ["sac", "ppo", "ddpgfd"])
def test_a_run_stopped_at_its_deadline_resumes_onto_the_uninterrupted_curve(tmp_path, algo):
    hyper = (
        {"hidden_sizes": (16, 16)}
        if algo == "ppo"  # updates late: seconds, not more
        else {**TINY, "learning_starts": 900}
    )
    prepared = prepare(RunSpec(algo, MOUNTAINCAR, 0, 1200, 400, 1, hyper))
    reference = execute(prepared, tmp_path / "reference", device="cpu")

    store = tmp_path / "limited"
    # a deadline already past: the run trains to its first checkpoint chance (an episode
    # end), saves there although checkpoints are off, and stops
    with pytest.raises(TimeLimitReached) as stop:
        execute(prepared, store, device="cpu", checkpoint_interval=0, deadline=time.time() - 1)
    work = store / f".{batch_id([prepared])}"  # a run training alone is a batch of one
    assert 0 < stop.value.step < 1200
    assert (work / CHECKPOINT_FILE).is_file() and not (store / prepared.run_id).exists()
    assert not list(store.glob(".lock-*"))

    resumed = execute(prepared, store, device="cpu")
    pd.testing.assert_frame_equal(
        curve_without_wall_time(resumed.path), curve_without_wall_time(reference.path)
    )
    segments = json.loads((resumed.path / SEGMENTS_FILE).read_text())
    assert [s["resumed_from_step"] for s in segments] == [0, stop.value.step]
    assert resumed.provenance["segments"] == segments


def test_a_run_interrupted_in_a_store_of_the_earlier_format_resumes_and_keeps_its_segments(
    tmp_path,
):
    """Stores written before 2026-12-04 call segments.json sittings.json: a resume reads
    them under that name and writes them under the new one."""
    prepared = prepare(
        RunSpec("sac", MOUNTAINCAR, 0, 1200, 400, 1, {**TINY, "learning_starts": 900})
    )
    with pytest.raises(TimeLimitReached) as stop:
        execute(prepared, tmp_path, device="cpu", checkpoint_interval=0, deadline=time.time() - 1)
    for directory in (
        tmp_path / f".{batch_id([prepared])}",
        partial_directory(prepared, tmp_path),
    ):
        (directory / SEGMENTS_FILE).rename(directory / EARLIER_SEGMENTS_FILE)

    resumed = execute(prepared, tmp_path, device="cpu")
    segments = resumed.provenance["segments"]
    assert [s["resumed_from_step"] for s in segments] == [0, stop.value.step]
    assert not (resumed.path / EARLIER_SEGMENTS_FILE).exists()


def test_a_seed_batch_stopped_at_its_deadline_resumes_onto_the_uninterrupted_curves(tmp_path):
    specs = [
        RunSpec("drl-eg", MOUNTAINCAR, seed, 400, 200, 1, {**TINY, "learning_starts": 300})
        for seed in (0, 1)
    ]
    reference = execute_batch([prepare(s) for s in specs], tmp_path / "reference", device="cpu")

    store = tmp_path / "limited"
    with pytest.raises(TimeLimitReached):
        execute_batch(
            [prepare(s) for s in specs],
            store,
            device="cpu",
            checkpoint_interval=0,
            deadline=time.time() - 1,
        )
    (batch_dir,) = store.glob(".batch-*")
    assert (batch_dir / CHECKPOINT_FILE).is_file()

    resumed = execute_batch([prepare(s) for s in specs], store, device="cpu")
    assert [r.path.name for r in resumed.runs] == [r.path.name for r in reference.runs]
    for ours, theirs in zip(resumed.runs, reference.runs):
        pd.testing.assert_frame_equal(
            curve_without_wall_time(ours.path), curve_without_wall_time(theirs.path)
        )


def test_a_grid_past_its_limit_stops_with_one_line_naming_the_same_command(
    tmp_path, capsys, monkeypatch
):
    # the limit counted as passed once the grid is prepared: no worker starts
    monkeypatch.setattr(experiments, "past", lambda deadline: deadline is not None)
    store = tmp_path / "store"
    args = [
        "fig3",
        "--profile",
        "smoke",
        "--algos",
        "sac",
        "--seeds",
        "1",
        "--store",
        str(store),
        "--out",
        str(tmp_path / "out"),
        "--time-limit",
        "90m",
    ]
    code = main(args)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == TIME_LIMIT_EXIT
    assert len(lines) == 1
    assert "0 of 1 runs finished and kept" in lines[0] and "1 not started" in lines[0]
    assert lines[0].endswith(
        "run the same command again to resume: python -m replicate " + " ".join(args)
    )
    assert not (tmp_path / "out").exists()  # the report waits for the runs
    assert experiments._deadline is None  # the limit ends with its command
