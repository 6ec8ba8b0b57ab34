"""Checks of the GPU path that fail loudly: run them on a GPU machine before trusting it.

    python benchmarks/gpu_checks.py                 # all checks, sized for under 10 minutes
    python benchmarks/gpu_checks.py OUT.json        # elsewhere than reports/bench/bench_gpu.json
    python benchmarks/gpu_checks.py --only kill-resume --only poison-ibrl

Each check is a function of a device that raises ``CheckFailed`` with what it expected and
what it found:

- ``gpu-tests``: the tests that skip without CUDA run, and none may skip or fail;
- ``graphed-vs-eager``: CUDA-graphed gradient steps and actions follow eager ones while
  the replay grows by a row before every step;
- ``poison-drl-eg``, ``poison-ibrl``: one member of a seed batch turns NaN (its policy; its
  critics) under the GPU's rule for reading losses; it fails alone, and a kill after the
  failure leaves the batch checkpoint and the other members' work in place;
- ``kill-resume``: a batch killed after a checkpoint and resumed ends on the curves of an
  uninterrupted one;
- ``checkpoint-memory``: saving and resuming a replay takes no second replay on the device;
- ``cuda-untouched``: CPU runs of the algorithms that fork random streams leave CUDA
  uninitialised;
- ``cpu-vs-device``: V-SAC and DRL-EG runs of the same seeds on CPU and on the device,
  their gap reported (the same initial policy: equal step-0 evaluations);
- ``seed-batches``: V-SAC seed batches of N = 1 to 64 on Hopper, env steps/s and memory.

The results go under ``"gpu_checks"`` into the JSON file (other keys there are kept); the
exit status is 1 when a check failed, 2 when torch has no CUDA GPU. ``--device cpu --small``
runs every check on CPU at tiny sizes, as tests/test_gpu_checks.py does: there
``cpu-vs-device`` compares CPU with itself (the curves must be equal) and device memory is
not measured.
"""

from __future__ import annotations

import argparse
import functools
import json
import multiprocessing as mp
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from baselines import offpolicy, training_loop  # noqa: E402
from baselines.common.checkpoint import load_checkpoint, save_checkpoint  # noqa: E402
from baselines.contract import agent_state  # noqa: E402
from baselines.sac import SACAgent, SACConfig  # noqa: E402
from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig  # noqa: E402
from baselines.training_loop import action_space  # noqa: E402
from benchmarks.batched import batched_rate  # noqa: E402
from replicate.store.runner import (  # noqa: E402
    CHECKPOINT_FILE,
    batch_id,
    execute_batch,
    is_complete,
    partial_directory,
    prepare,
)
from replicate.store.spec import RunSpec  # noqa: E402
from tests.helpers import MOUNTAINCAR, TINY  # noqa: E402

DEFAULT_OUT = ROOT / "reports" / "bench" / "bench_gpu.json"
HOPPER = "Hopper-v5"


class CheckFailed(AssertionError):
    """A check found what it must not: the message says what it expected and what it got."""


def require(condition: bool, message: str) -> None:
    if not condition:
        raise CheckFailed(message)


def require_cuda() -> str:
    """The GPU's name; fails on a CPU-only build of torch, or where torch sees no GPU."""
    if torch.version.cuda is None:
        raise CheckFailed(
            f"this torch ({torch.__version__}) is a CPU-only build: the GPU checks need a CUDA "
            "build of torch on a machine with a GPU"
        )
    if not torch.cuda.is_available():
        raise CheckFailed(f"torch {torch.__version__} (CUDA {torch.version.cuda}) sees no GPU")
    return torch.cuda.get_device_name()


@dataclass(frozen=True)
class Sizes:
    """How much each check trains and measures."""

    hyper: dict[str, Any]  # the short MountainCar batches (poisoned, killed and resumed)
    run_steps: int
    eval_interval: int
    checkpoint_interval: int
    graph_config: dict[str, Any]  # graphed against eager: Hopper networks and minibatch
    graph_members: int
    graph_updates: int
    replay_members: int  # checkpoint memory: a Hopper replay this many members deep ...
    replay_rows: int  # ... holding this many rows each, in room for 1.5x as many
    compare_hyper: dict[str, Any]  # CPU against the device: Hopper runs
    compare_seeds: tuple[int, ...]
    compare_steps: int
    compare_eval_interval: int
    scaling_members: tuple[int, ...]  # seed batches on Hopper, paper sizes
    scaling_steps: int
    scaling_warmup: int


# On a GPU machine with 16 cores: about 6-8 minutes in all (the GPU tests and the CPU side of
# cpu-vs-device are the longest).
FULL = Sizes(
    hyper={"learning_starts": 200},
    run_steps=1200,
    eval_interval=400,
    checkpoint_interval=300,
    graph_config={},
    graph_members=3,
    graph_updates=200,
    replay_members=8,
    replay_rows=250_000,
    compare_hyper={"learning_starts": 1000},
    compare_seeds=(0, 1),
    compare_steps=2500,
    compare_eval_interval=500,
    scaling_members=(1, 2, 4, 8, 16, 32, 64),
    scaling_steps=300,
    scaling_warmup=300,
)

# The tests' sizes: every check on CPU in seconds.
SMALL = Sizes(
    hyper=dict(TINY),
    run_steps=400,
    eval_interval=200,
    checkpoint_interval=100,
    graph_config={"hidden_sizes": (16, 16), "batch_size": 16},
    graph_members=2,
    graph_updates=6,
    replay_members=2,
    replay_rows=300,
    compare_hyper=dict(TINY),
    compare_seeds=(0, 1),
    compare_steps=200,
    compare_eval_interval=100,
    scaling_members=(1, 2),
    scaling_steps=5,
    scaling_warmup=10,
)


# --- gpu-tests ---------------------------------------------------------------------------


def needs_cuda(item: Any) -> bool:
    """Whether a collected test skips without CUDA (its skipif reason names CUDA)."""
    return any("CUDA" in str(m.kwargs.get("reason", "")) for m in item.iter_markers("skipif"))


class CudaTestSelection:
    """A pytest plugin: keeps only the tests that need CUDA and records their outcomes."""

    def __init__(self) -> None:
        self.selected: list[str] = []
        self.outcomes: dict[str, str] = {}

    def pytest_collection_modifyitems(self, config: Any, items: list) -> None:
        keep = [item for item in items if needs_cuda(item)]
        kept = {id(item) for item in keep}
        config.hook.pytest_deselected(items=[i for i in items if id(i) not in kept])
        items[:] = keep
        self.selected = [item.nodeid for item in keep]

    def pytest_runtest_logreport(self, report: Any) -> None:
        # a skip or an error can come at setup or teardown; a pass only counts at the call
        if report.when == "call" or report.outcome != "passed":
            self.outcomes[report.nodeid] = report.outcome


_PYTEST_CHILD = """
import json, sys
import pytest
from benchmarks.gpu_checks import CudaTestSelection
selection = CudaTestSelection()
code = pytest.main(sys.argv[2:], plugins=[selection])
with open(sys.argv[1], "w") as f:
    json.dump({"exit": int(code), "selected": selection.selected,
               "outcomes": selection.outcomes}, f)
"""


def gpu_tests(device: str, sizes: Sizes, work: Path) -> dict[str, Any]:
    """On a GPU, the tests that skip without CUDA, run: all pass, none skips. On CPU they are
    only collected: there must be some (a renamed skip reason would hide them all)."""
    files = [
        str(path.relative_to(ROOT))
        for path in sorted((ROOT / "tests").glob("test_*.py"))
        if "cuda.is_available()" in path.read_text()
    ]
    require(bool(files), "no test file has a test that needs CUDA")
    if device != "cpu":
        require_cuda()
    summary_path = work / "pytest.json"
    command = [sys.executable, "-c", _PYTEST_CHILD, str(summary_path), *files, "-q"]
    command += ["-p", "no:cacheprovider"] + (["--collect-only"] if device == "cpu" else [])
    done = subprocess.run(
        command, cwd=ROOT, capture_output=True, text=True, timeout=120 if device == "cpu" else 480
    )
    require(
        summary_path.is_file(),
        f"pytest did not report (exit {done.returncode}): {done.stderr[-2000:]}",
    )
    summary = json.loads(summary_path.read_text())
    selected, outcomes = summary["selected"], summary["outcomes"]
    require(bool(selected), f"no test that needs CUDA was collected from {files}")
    require(summary["exit"] == 0, f"pytest exited {summary['exit']}: {done.stdout[-3000:]}")
    if device != "cpu":
        skipped = sorted(n for n, o in outcomes.items() if o == "skipped")
        failed = sorted(n for n, o in outcomes.items() if o == "failed")
        missing = sorted(set(selected) - set(outcomes))
        require(not skipped, f"GPU tests skipped on the GPU: {skipped}")
        require(not failed, f"GPU tests failed: {failed}\n{done.stdout[-3000:]}")
        require(not missing, f"GPU tests that never reported: {missing}")
    return {"files": files, "tests": selected, "outcomes": outcomes}


# --- graphed-vs-eager --------------------------------------------------------------------


def _add_rows(replay: Any, rng: np.random.Generator, rows: int) -> None:
    members, obs_dim, act_dim = len(replay.data), replay.obs_dim, replay.act_dim
    for _ in range(rows):
        replay.add(
            rng.normal(size=(members, obs_dim)),
            rng.uniform(-1, 1, (members, act_dim)),
            rng.normal(size=members),
            rng.normal(size=(members, obs_dim)),
            (rng.random(members) < 0.05).astype(np.float32),
        )


def graphed_vs_eager(device: str, sizes: Sizes, work: Path) -> dict[str, Any]:
    """V-SAC and twin-Q SAC agents of the same seeds, one replaying its gradient step and its
    action as CUDA graphs, one running them eagerly, both from the same seed of the device
    stream before every call, on one replay that grows by a row before every step: the same
    losses, actions and final weights (to 1e-4; on CPU, where nothing is graphed, exactly)."""
    obs_dim, act_dim, _, _ = action_space(HOPPER)
    exact = device == "cpu"
    report: dict[str, Any] = {}
    for kind, agent_cls, config_cls in (
        ("sac", SACAgent, SACConfig),
        ("sac-twin-q", TwinQSACAgent, TwinQSACConfig),
    ):
        config = config_cls(**sizes.graph_config)
        seeds = list(range(sizes.graph_members))
        graphed = agent_cls(seeds, HOPPER, config, device=device, cuda_graphs=True)
        eager = agent_cls(seeds, HOPPER, config, device=device, cuda_graphs=False)
        replay = graphed.make_replay(len(seeds), obs_dim, config.batch_size + sizes.graph_updates)
        graphed.buffer = eager.buffer = replay  # read-only in the step: one serves both
        rng = np.random.default_rng(0)
        _add_rows(replay, rng, config.batch_size)
        worst = 0.0

        def agree(a: torch.Tensor, b: torch.Tensor, what: str) -> None:
            nonlocal worst
            a, b = a.detach().cpu(), b.detach().cpu()
            worst = max(worst, float((a - b).abs().max()))
            same = torch.equal(a, b) if exact else torch.allclose(a, b, rtol=1e-4, atol=1e-5)
            require(same, f"{kind}: graphed and eager {what} differ by {worst:.3g}")

        for i in range(sizes.graph_updates):
            _add_rows(replay, rng, 1)  # the graph must read the replay's size, not keep it
            losses = []
            for agent in (graphed, eager):
                torch.manual_seed(1000 + i)
                agent._size.fill_(replay.size)
                out = agent._update_graph(size=agent._size)
                losses.append({name: value.clone() for name, value in out.items()})
            for name in losses[1]:
                agree(losses[0][name], losses[1][name], f"{name} at step {i}")
            obs = rng.normal(size=(len(seeds), obs_dim)).astype(np.float32)
            actions = []
            for agent in (graphed, eager):
                torch.manual_seed(2000 + i)
                actions.append(torch.from_numpy(agent.act(obs)))
            agree(actions[0], actions[1], f"actions at step {i}")
        for name in ("policy", "critics"):
            for a, b in zip(
                getattr(graphed, name).parameters(), getattr(eager, name).parameters(), strict=True
            ):
                agree(a, b, f"{name} weights after {sizes.graph_updates} steps")
        captured = graphed._update_graph.graph is not None and graphed._act_graph.graph is not None
        if device != "cpu":
            require(captured, f"{kind}: no CUDA graph was captured on {device}")
        report[kind] = {
            "max_abs_difference": worst,
            "graphs_captured": captured,
            "replay_rows": [config.batch_size + 1, replay.size],
        }
    return report


# --- poison-drl-eg, poison-ibrl, kill-resume ----------------------------------------------


class _Killed(Exception):
    """Stands for a kill: not an error the runner treats as recurring, so it keeps what a
    kill would leave (the batch checkpoint, the members' unfinished work)."""


def killed_at(call: int) -> Callable[[int], None]:
    """A progress callback that stops the batch at its ``call``-th call (about that step)."""
    seen = [0]

    def on_steps(n: int) -> None:
        seen[0] += 1
        if seen[0] == call:
            raise _Killed

    return on_steps


@contextmanager
def poisoned(member: int, module: str, rows: int) -> Iterator[None]:
    """After every gradient step, member ``member``'s weights in ``module`` (``rows``
    stacked rows per member: 2 for twin critics) are NaN."""
    original = offpolicy.run_off_policy

    def run(bctx: Any, agent: Any, explorer: Any) -> Any:
        update = agent.update

        def update_then_poison(rngs: list) -> dict[str, torch.Tensor]:
            losses = update(rngs)
            with torch.no_grad():
                for weight in getattr(agent, module).parameters():
                    weight[member * rows : (member + 1) * rows] = float("nan")
            return losses

        agent.update = update_then_poison
        return original(bctx, agent, explorer)

    with mock.patch.object(offpolicy, "run_off_policy", run):
        yield


@contextmanager
def gpu_check_rule(device: str) -> Iterator[None]:
    """On CPU, the losses read as on a GPU (every 100 steps), as a GPU batch would."""
    if device != "cpu":
        yield
        return
    original = training_loop.losses_due
    with mock.patch.object(
        training_loop, "losses_due", lambda kind, step, total: original("cuda", step, total)
    ):
        yield


# What turns NaN in the poisoned member, and each member's settings. DRL-EG: the policy of a
# member that is never guided (T2 = 0; the others are), so its actions turn non-finite, and
# its next states would reach the KD-tree all members share. IBRL: the critics, so its losses
# turn non-finite (on a GPU they are read every 100 steps) and its actions soon after.
POISON = {
    "drl-eg": ("policy", 1, [{"guide_threshold": t} for t in (0.1, 0.0, 0.1)]),
    "ibrl": ("critics", 2, [{}, {}, {}]),
}


def _members(algo: str, sizes: Sizes, seeds: tuple[int, ...], extra: list[dict]) -> list:
    return [
        prepare(
            RunSpec(
                algo,
                MOUNTAINCAR,
                seed,
                sizes.run_steps,
                sizes.eval_interval,
                1,
                {**sizes.hyper, **mine},
            )
        )
        for seed, mine in zip(seeds, extra, strict=True)
    ]


def poisoned_member(device: str, sizes: Sizes, work: Path, algo: str) -> dict[str, Any]:
    """A batch of 3 with member 1 poisoned, killed some steps after it failed: the batch
    checkpoint names member 1 alone as failed, and the other members' work is on disk; then
    resumed, member 1 fails and the others land complete."""
    module, rows, extra = POISON[algo]
    members, victim = _members(algo, sizes, (0, 1, 2), extra), 1
    store = work / "store"
    checkpoint = store / f".{batch_id(members)}" / CHECKPOINT_FILE
    learning_starts = members[0].config.learning_starts
    kill_at = learning_starts + 2 * sizes.checkpoint_interval  # a checkpoint after the failure
    with gpu_check_rule(device):
        with poisoned(victim, module, rows):
            try:
                execute_batch(
                    members,
                    store,
                    killed_at(kill_at),
                    sizes.checkpoint_interval,
                    device,
                )
            except _Killed:
                pass
            except Exception as exc:
                raise CheckFailed(
                    f"{algo}: the poisoned batch failed as a whole ({type(exc).__name__}: "
                    f"{exc}); batch checkpoint kept: {checkpoint.is_file()}; work kept: "
                    f"{[partial_directory(p, store).is_dir() for p in members]}"
                ) from exc
            else:
                raise CheckFailed(f"{algo}: the batch finished before step {kill_at}")
        require(checkpoint.is_file(), f"{algo}: the batch checkpoint is gone after the kill")
        saved = load_checkpoint(checkpoint)
        failures = {int(k): reason for k, reason in saved["failures"].items()}
        require(
            list(failures) == [victim],
            f"{algo}: the checkpoint at step {saved['step']} has failed members "
            f"{failures}, not member {victim} alone",
        )
        for k, p in enumerate(members):
            curve = partial_directory(p, store) / "curve.csv"
            require(
                k == victim or (curve.is_file() and len(curve.read_text().splitlines()) > 1),
                f"{algo}: member {k}'s curve so far is gone",
            )
        outcome = execute_batch(
            members, store, checkpoint_interval=sizes.checkpoint_interval, device=device
        )
    failed = [run_id for run_id, _ in outcome.failed]
    require(
        failed == [members[victim].run_id],
        f"{algo}: after the resume the failed runs are {failed}, not member {victim}'s",
    )
    for k, p in enumerate(members):
        if k != victim:
            require(is_complete(p.directory(store)), f"{algo}: member {k} did not land")
    returns = [r.final_return for r in outcome.runs]
    require(all(np.isfinite(returns)), f"{algo}: the others' final returns {returns}")
    require(not list(store.glob(".batch-*")), f"{algo}: the batch directory outlived the batch")
    return {
        "poisoned": f"member {victim}'s {module}",
        "reason": failures[victim],
        "checkpoint_step": int(saved["step"]),
        "others_final_returns": returns,
    }


def kill_resume(device: str, sizes: Sizes, work: Path) -> dict[str, Any]:
    """A DRL-EG batch of 2 killed two thirds of the way in and started again ends on the
    curves of the same batch trained without a stop (every column but wall time), and its
    runs record two stretches of training."""
    members = _members("drl-eg", sizes, (0, 1), [{"guide_threshold": 0.1}] * 2)
    whole = execute_batch(
        members, work / "whole", checkpoint_interval=sizes.checkpoint_interval, device=device
    ).runs
    store = work / "killed"
    try:
        execute_batch(
            members, store, killed_at(2 * sizes.run_steps // 3), sizes.checkpoint_interval, device
        )
    except _Killed:
        pass
    else:
        raise CheckFailed("the batch was not stopped")
    resumed = execute_batch(
        members, store, checkpoint_interval=sizes.checkpoint_interval, device=device
    ).runs
    require(len(resumed) == len(whole) == 2, f"runs landed: {len(whole)} and {len(resumed)}")
    report = {}
    for a, b in zip(whole, resumed, strict=True):
        one, two = (r.curve.drop(columns=["wall_s"]) for r in (a, b))
        if not one.equals(two):
            gap = float(np.nanmax(np.abs(one["return_mean"] - two["return_mean"])))
            # is it the resume, or does the device not repeat a run at all?
            again = execute_batch(members, work / "again", device=device).runs
            repeats = all(
                x.curve.drop(columns=["wall_s"]).equals(y.curve.drop(columns=["wall_s"]))
                for x, y in zip(whole, again, strict=True)
            )
            raise CheckFailed(
                f"{a.path.name}: the resumed curve differs from the uninterrupted one "
                f"(largest return gap {gap:.4g}); two uninterrupted runs on {device} "
                f"{'agree' if repeats else 'differ too'}\n{one}\n{two}"
            )
        segments = json.loads((b.path / "segments.json").read_text())
        require(
            len(segments) == 2 and segments[1]["resumed_from_step"] > 0,
            f"{b.path.name}: segments {segments}",
        )
        report[a.path.name] = {"resumed_from_step": segments[1]["resumed_from_step"]}
    return report


# --- checkpoint-memory -------------------------------------------------------------------


@contextmanager
def device_peak(device: str) -> Iterator[dict[str, int | None]]:
    """The peak device memory allocated inside the block beyond what was allocated before
    (None on CPU, which keeps no such count)."""
    box: dict[str, int | None] = {"bytes": None}
    if device == "cpu":
        yield box
        return
    torch.cuda.synchronize()
    torch.cuda.reset_peak_memory_stats()
    before = torch.cuda.memory_allocated()
    yield box
    torch.cuda.synchronize()
    box["bytes"] = torch.cuda.max_memory_allocated() - before


def _tensor_bytes(state: Any) -> int:
    if isinstance(state, torch.Tensor):
        return state.numel() * state.element_size()
    if isinstance(state, dict):
        return sum(_tensor_bytes(v) for v in state.values())
    if isinstance(state, list | tuple):
        return sum(_tensor_bytes(v) for v in state)
    return 0


def checkpoint_memory(device: str, sizes: Sizes, work: Path) -> dict[str, Any]:
    """A V-SAC batch's replay, filled to two thirds: taking its state, saving the whole
    checkpoint and loading the replay back each need well under a second replay on the
    device (on CPU: the file holds the filled rows only); the rows come back exactly."""
    obs_dim, _, _, _ = action_space(HOPPER)
    members, rows = sizes.replay_members, sizes.replay_rows
    agent = SACAgent(list(range(members)), HOPPER, SACConfig(**sizes.graph_config), device=device)
    replay = agent.make_replay(members, obs_dim, rows + rows // 2)
    replay.data[:, :rows].normal_()
    replay.size = replay.position = rows
    filled = replay.data[:, :rows].numel() * replay.data.element_size()
    networks = _tensor_bytes(agent_state(agent))
    path = work / "checkpoint.pt"
    with device_peak(device) as taking:
        state = replay.state_dict()
    with device_peak(device) as saving:
        save_checkpoint(path, {"agent": agent_state(agent), "buffer": state})
    del state
    back = agent.make_replay(members, obs_dim, rows + rows // 2)
    loaded = load_checkpoint(path)
    with device_peak(device) as loading:
        back.load_state_dict(loaded["buffer"])
    for k in range(members):
        require(torch.equal(back.data[k, :rows], replay.data[k, :rows]), f"member {k}'s rows")
    require(back.size == rows and back.position == rows, "the replay's size and position")
    file_bytes = path.stat().st_size
    require(
        file_bytes <= 1.05 * filled + 3 * networks + 2**20,
        f"the checkpoint holds {file_bytes} bytes for {filled} bytes of filled replay",
    )
    report = {
        "replay_filled_bytes": filled,
        "replay_capacity_bytes": replay.data.numel() * replay.data.element_size(),
        "networks_bytes": networks,
        "file_bytes": file_bytes,
        "peak_device_bytes": {
            "replay state": taking["bytes"],
            "saving": saving["bytes"],
            "loading the replay": loading["bytes"],
        },
    }
    if device != "cpu":
        allowed = 0.1 * filled  # a second replay would be 1.0x
        for what, peak in report["peak_device_bytes"].items():
            extra = networks * 1.5 if what == "saving" else 0  # the agent's state is copied
            require(
                peak <= allowed + extra,
                f"{what}: {peak / 2**20:.1f} MiB more on the device for a replay of "
                f"{filled / 2**20:.1f} MiB",
            )
        report["peak / replay"] = {
            k: round(v / filled, 4) for k, v in report["peak_device_bytes"].items()
        }
    return report


# --- cuda-untouched ------------------------------------------------------------------------


# A fresh interpreter trains CPU runs and says whether CUDA was initialised. Without a GPU,
# torch would never initialise it, so a tripwire stands for one: it counts one device and
# records every call that would read or seed it.
_CUDA_CHILD = """
import json, sys
from pathlib import Path
import torch
touched = []
if not torch.cuda.is_available():
    def tripwire(name, value=None):
        def call(*args, **kwargs):
            touched.append(name)
            return value
        return call
    torch.cuda.device_count = lambda: 1
    torch.cuda.get_rng_state = tripwire("get_rng_state", torch.empty(0, dtype=torch.uint8))
    torch.cuda.set_rng_state = tripwire("set_rng_state")
    torch.cuda.init = tripwire("init")
    torch.cuda._lazy_init = tripwire("_lazy_init")
exec(sys.argv[2])
from benchmarks.gpu_checks import train_cpu_runs
train_cpu_runs(Path(sys.argv[1]), sys.argv[3].split(","))
print(json.dumps({"initialized": torch.cuda.is_initialized(), "touched": touched}))
"""

# the CPU runs: each algorithm whose setup forks random streams (a guider's or a BC fit)
CPU_RUNS = {
    "sac": {},
    "drl-eg": {"guider": "neural", "neural_guider_steps": 20, "neural_guider_hidden": (16, 16)},
    "ibrl": {"imitation": "bc", "bc_steps": 20, "bc_hidden": (16, 16)},
    "jsrl": {"imitation": "bc", "bc_steps": 20, "bc_hidden": (16, 16), "guide_horizon": 50},
}


def train_cpu_runs(store: Path, algos: list[str]) -> None:
    """One tiny MountainCar run of each of ``algos`` (``CPU_RUNS``) through the runner, on CPU."""
    for algo in algos:
        spec = RunSpec(algo, MOUNTAINCAR, 0, 250, 250, 1, {**TINY, **CPU_RUNS[algo]})
        outcome = execute_batch([prepare(spec)], store, device="cpu")
        if outcome.failed:
            raise RuntimeError(f"{algo}: {outcome.failed}")


def cuda_untouched(
    device: str, sizes: Sizes, work: Path, prelude: str = "", algos: tuple[str, ...] = ()
) -> dict[str, Any]:
    """CPU runs of V-SAC, DRL-EG (neural guider), IBRL and JSRL (BC) in a fresh process leave
    CUDA uninitialised (``algos``: fewer of them; ``prelude``: code the process runs first,
    which the tests make touch CUDA)."""
    algos = algos or tuple(CPU_RUNS)
    done = subprocess.run(
        [sys.executable, "-c", _CUDA_CHILD, str(work / "store"), prelude, ",".join(algos)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    require(done.returncode == 0, f"the CPU runs failed: {done.stderr[-3000:]}")
    found = json.loads(done.stdout.strip().splitlines()[-1])
    require(
        not found["initialized"] and not found["touched"],
        f"CPU runs of {sorted(algos)} touched CUDA: initialised {found['initialized']}, "
        f"calls {sorted(set(found['touched']))}",
    )
    return {"runs": sorted(algos), "gpu_present": torch.cuda.is_available(), **found}


# --- cpu-vs-device -------------------------------------------------------------------------

COMPARED = ("sac", "drl-eg")


def train_curves(algo: str, device: str, sizes: Sizes, store: Path) -> dict[int, dict]:
    """Each seed's evaluation curve (steps, mean returns) of a batch of ``algo`` on Hopper."""
    specs = [
        RunSpec(
            algo,
            HOPPER,
            s,
            sizes.compare_steps,
            sizes.compare_eval_interval,
            1,
            dict(sizes.compare_hyper),
        )
        for s in sizes.compare_seeds
    ]
    outcome = execute_batch([prepare(s) for s in specs], store, device=device)
    if outcome.failed:
        raise CheckFailed(f"{algo} on {device}: {outcome.failed}")
    return {
        run.spec["seed"]: {
            "step": run.curve["step"].tolist(),
            "return_mean": run.curve["return_mean"].tolist(),
        }
        for run in outcome.runs
    }


def cpu_vs_device(device: str, sizes: Sizes, work: Path) -> dict[str, Any]:
    """V-SAC and DRL-EG batches of the same seeds on CPU and on ``device``: their returns'
    gap at each evaluation. Step 0 evaluates the same initial policy on both (to 2%); on CPU
    against CPU every point must be equal. The CPU side trains in other processes meanwhile."""
    train = functools.partial(train_curves, sizes=sizes)
    if device == "cpu":
        cpu = {a: train(a, "cpu", store=work / f"cpu-{a}") for a in COMPARED}
        other = {a: train(a, "cpu", store=work / f"again-{a}") for a in COMPARED}
    else:
        spawn = mp.get_context("spawn")
        with ProcessPoolExecutor(len(COMPARED), mp_context=spawn) as pool:
            jobs = {a: pool.submit(train, a, "cpu", store=work / f"cpu-{a}") for a in COMPARED}
            other = {a: train(a, device, store=work / f"{device}-{a}") for a in COMPARED}
            cpu = {a: job.result() for a, job in jobs.items()}
    report: dict[str, Any] = {}
    for algo in COMPARED:
        rows = {}
        for seed, mine in cpu[algo].items():
            theirs = other[algo][seed]
            require(mine["step"] == theirs["step"], f"{algo} seed {seed}: evaluation steps")
            a, b = np.array(mine["return_mean"]), np.array(theirs["return_mean"])
            if device == "cpu":
                require(np.array_equal(a, b), f"{algo} seed {seed}: CPU curves differ: {a} {b}")
            else:
                require(
                    np.isclose(a[0], b[0], rtol=0.02),
                    f"{algo} seed {seed}: step-0 returns {a[0]:.3f} on CPU, {b[0]:.3f} on "
                    f"{device}: not the same initial policy?",
                )
            rows[seed] = {
                "cpu": a.round(3).tolist(),
                device if device != "cpu" else "cpu again": b.round(3).tolist(),
                "final_gap": round(float(b[-1] - a[-1]), 3),
                "mean_abs_gap": round(float(np.abs(b - a).mean()), 3),
            }
        report[algo] = {
            "steps": cpu[algo][sizes.compare_seeds[0]]["step"],
            "seeds": rows,
            "mean_final_gap": round(float(np.mean([r["final_gap"] for r in rows.values()])), 3),
        }
    return report


# --- seed-batches --------------------------------------------------------------------------


def env_workers_for(members: int) -> int:
    """Processes stepping a batch's envs: none for small batches (the IPC costs more)."""
    return 0 if members < 16 else 4


def seed_batches(device: str, sizes: Sizes, work: Path) -> dict[str, Any]:
    """V-SAC seed batches of N members on Hopper (paper sizes): env steps/s summed over the
    members after the warm-up, per member, and the device memory; every batch must train."""
    rows = []
    for members in sizes.scaling_members:
        row = batched_rate(
            "sac",
            HOPPER,
            members,
            sizes.scaling_steps,
            device,
            env_workers_for(members),
            warmup=sizes.scaling_warmup,
        )
        require(
            np.isfinite(row["env_steps_per_s"]) and row["env_steps_per_s"] > 0,
            f"N = {members}: {row}",
        )
        row["per_member_steps_per_s"] = round(row["env_steps_per_s"] / members, 1)
        rows.append(row)
        print(f"    N = {members}: {row['env_steps_per_s']} env steps/s", flush=True)
    one = rows[0]["env_steps_per_s"]
    return {"batches": rows, "largest / smallest": round(rows[-1]["env_steps_per_s"] / one, 2)}


# --- running them --------------------------------------------------------------------------

CHECKS: dict[str, Callable[[str, Sizes, Path], dict[str, Any]]] = {
    "gpu-tests": gpu_tests,
    "graphed-vs-eager": graphed_vs_eager,
    "poison-drl-eg": functools.partial(poisoned_member, algo="drl-eg"),
    "poison-ibrl": functools.partial(poisoned_member, algo="ibrl"),
    "kill-resume": kill_resume,
    "checkpoint-memory": checkpoint_memory,
    "cuda-untouched": cuda_untouched,
    "cpu-vs-device": cpu_vs_device,
    "seed-batches": seed_batches,
}


def write_section(out: Path, section: str, value: dict[str, Any]) -> None:
    """Put ``value`` under ``section`` in the JSON file ``out``, keeping its other keys."""
    data: dict[str, Any] = {}
    if out.is_file():
        try:
            data = json.loads(out.read_text())
        except json.JSONDecodeError:
            data = {}
    data[section] = value
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=2, default=str) + "\n")


def run_checks(
    device: str, sizes: Sizes, names: list[str] | None = None, out: Path | None = None
) -> dict[str, Any]:
    """Run the checks (``names``, or all) in turn, each in a directory of its own; a check
    that fails or crashes is recorded and the others still run. Written to ``out`` after
    each check, so a cut-off run keeps what it finished."""
    started = time.perf_counter()
    results: dict[str, Any] = {
        "device": device,
        "gpu": torch.cuda.get_device_name() if device != "cpu" else None,
        "torch": torch.__version__,
        "sizes": "small" if sizes == SMALL else "full" if sizes == FULL else asdict(sizes),
        "checks": {},
    }
    for name, check in CHECKS.items():
        if names and name not in names:
            continue
        print(f"{name} ...", flush=True)
        began = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix=f"gpu-check-{name}-") as work:
            try:
                entry = {"ok": True, "result": check(device, sizes, Path(work))}
            except CheckFailed as exc:
                entry = {"ok": False, "error": str(exc)}
            except Exception:  # a crash fails its check; the others still run
                entry = {"ok": False, "error": traceback.format_exc()}
        entry["seconds"] = round(time.perf_counter() - began, 1)
        results["checks"][name] = entry
        verdict = "ok" if entry["ok"] else "FAILED: " + entry["error"]
        print(f"{name}: {verdict} ({entry['seconds']} s)", flush=True)
        results["failed"] = [n for n, e in results["checks"].items() if not e["ok"]]
        results["wall_s"] = round(time.perf_counter() - started, 1)
        if out is not None:
            write_section(out, "gpu_checks", results)
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    parser.add_argument("--small", action="store_true", help="tiny sizes (the tests')")
    parser.add_argument("--only", action="append", choices=sorted(CHECKS), help="repeatable")
    args = parser.parse_args(argv)
    if args.device == "cuda":
        try:
            print(f"GPU: {require_cuda()}", flush=True)
        except CheckFailed as exc:
            print(f"gpu_checks: {exc}", file=sys.stderr)
            return 2
    results = run_checks(args.device, SMALL if args.small else FULL, args.only, args.out)
    print(f"written: {args.out} ({results['wall_s']} s)")
    if results["failed"]:
        print(f"FAILED: {', '.join(results['failed'])}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
