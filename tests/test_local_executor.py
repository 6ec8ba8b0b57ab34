"""The local process pool: errors cross it intact, and its workers do not outlive it."""

import fcntl
import os
import pickle
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from replicate.demos import DemoError
from replicate.errors import HarnessError
from replicate.grids.experiments import GridOptions, run_grid
from replicate.store.runner import RunLockedError, prepare
from replicate.store.spec import RunSpec
from tests.helpers import MOUNTAINCAR, TINY


def tiny_spec(seed: int, steps: int = 300) -> RunSpec:
    return RunSpec("sac", MOUNTAINCAR, seed, steps, 100, 1, dict(TINY))


def test_harness_errors_survive_pickling():
    for error in (
        HarnessError("p", "f"),
        DemoError("bad file", "remake it"),
        RunLockedError("locked", "wait"),
    ):
        copy = pickle.loads(pickle.dumps(error))
        assert type(copy) is type(error) and str(copy) == str(error)
        assert (copy.problem, copy.fix) == (error.problem, error.fix)


def test_a_run_locked_elsewhere_fails_alone_and_the_grid_goes_on(tmp_path):
    locked_spec, free_spec = tiny_spec(0), tiny_spec(1)
    tmp_path.mkdir(exist_ok=True)
    lock_path = tmp_path / f".lock-{prepare(locked_spec).run_id}"
    with open(lock_path, "w") as held:  # another process is training this run
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        outcome = run_grid([locked_spec, free_spec], tmp_path, GridOptions(workers=1))
    assert [r.spec["seed"] for r in outcome.runs] == [1]
    assert len(outcome.failed) == 1
    run_id, reason = outcome.failed[0]
    assert run_id == prepare(locked_spec).run_id
    assert reason.startswith("RunLockedError") and "another process" in reason


def _children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_workers_stop_when_the_figure_process_is_killed(tmp_path):
    script = textwrap.dedent(f"""
        from replicate.grids.experiments import GridOptions, run_grid
        from tests.test_local_executor import tiny_spec
        run_grid([tiny_spec(0, steps=200_000)], {str(tmp_path)!r},
                 GridOptions(workers=1, checkpoint_interval=200))
    """)
    root = Path(__file__).resolve().parents[1]
    main = subprocess.Popen(
        [sys.executable, "-c", script],
        cwd=root,
        env=dict(os.environ, MUJOCO_GL="disable"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while time.time() < deadline and not list(tmp_path.glob(".*/checkpoint.pt")):
        time.sleep(0.2)
    assert list(tmp_path.glob(".*/checkpoint.pt")), "training never checkpointed"
    descendants = _children(main.pid)
    descendants += [grandchild for child in descendants for grandchild in _children(child)]
    main.send_signal(signal.SIGKILL)
    main.wait()
    deadline = time.time() + 30
    while time.time() < deadline and any(_alive(pid) for pid in descendants):
        time.sleep(0.2)
    leftovers = [pid for pid in descendants if _alive(pid)]
    names = [
        Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")[-90:] for pid in leftovers
    ]
    for pid in leftovers:
        os.kill(pid, signal.SIGKILL)
    assert not leftovers, f"processes outlived the killed figure process: {names}"
    assert list(tmp_path.glob(".*/checkpoint.pt"))  # resumable, not discarded


def test_estimates_take_a_batch_process_speed_as_its_members_summed(tmp_path):
    import json

    from replicate.grids.planning import estimate_minutes

    def stored(
        name: str, rate: float, size: int | None, algo: str = "sac", device: str = "cpu"
    ) -> None:
        run = tmp_path / name
        run.mkdir()
        (run / "spec.json").write_text(json.dumps({"algo": algo, "env_id": MOUNTAINCAR}))
        (run / "curve.csv").write_text("step,return_mean\n0,0\n")
        batch = {"size": size} if size else {}
        (run / "provenance.json").write_text(
            json.dumps({"env_steps_per_s": rate, "batch": batch, "device": device})
        )

    stored("sac__a", 30.0, 3)  # a member of a batch of 3: the process stepped 90/s
    stored("sac__b", 90.0, None)  # one run per process at 90/s
    stored("ppo__c", 1800.0, None, algo="ppo")
    one = prepare(
        RunSpec(algo="sac", env_id=MOUNTAINCAR, seed=0, total_steps=5400, eval_interval=1800)
    )
    assert estimate_minutes([one], tmp_path, workers=1) == 1.0
    batch = [
        prepare(
            RunSpec(algo="sac", env_id=MOUNTAINCAR, seed=s, total_steps=5400, eval_interval=1800)
        )
        for s in range(2)
    ]
    assert estimate_minutes([batch], tmp_path, workers=1) == 2.0
    # an algorithm never timed steps as the env's slowest timed one: sac's 90/s, not ppo's
    untimed = prepare(
        RunSpec(algo="sac-twin-q", env_id=MOUNTAINCAR, seed=0, total_steps=5400, eval_interval=1800)
    )
    assert estimate_minutes([untimed], tmp_path, workers=1) == 1.0
    # a GPU batch's speed says nothing of a CPU process's: a CPU plan ignores it, a GPU one
    # takes it, and a CPU speed where no run was timed on a GPU (ppo's)
    stored("sac__gpu", 180.0, 5, device="cuda (NVIDIA H100 80GB HBM3, CUDA 13.0)")
    assert estimate_minutes([one], tmp_path, workers=1) == 1.0
    assert estimate_minutes([one], tmp_path, workers=1, on_gpu=True) == 0.1
    assert estimate_minutes([untimed], tmp_path, workers=1, on_gpu=True) == 0.1
    ppo = prepare(
        RunSpec(algo="ppo", env_id=MOUNTAINCAR, seed=0, total_steps=5400, eval_interval=1800)
    )
    assert estimate_minutes([ppo], tmp_path, workers=1, on_gpu=True) == 0.05
