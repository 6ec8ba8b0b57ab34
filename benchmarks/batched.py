"""Seed batches of the off-policy trainer (``baselines.offpolicy``) against one run.

There is one trainer: a run trained alone is a seed batch of one (the registry's
``Algorithm.train``), so every comparison here is the same trainer at N members against
N = 1, in the same bench run.

CPU section (``--cpu``): on this machine's cores, one process per core, each training
N = 2, 4, 8 members of V-SAC on Hopper-v5, against one run per process; env steps per
second summed over the machine. N = 1 is measured too, through ``train_batch`` rather than
``train``: the same code, so its ratio to one run is the bench's own noise. Then one V-SAC
update in fp32 against bf16 autocast and bf16 products.

RLFD CPU section (``--rlfd-cpu``): IBRL and RLPD on the sparse cartpole, a batch of 5 seeds
in one process against one run, on one thread each.

GPU section (``--gpu``): N = 8, 16, 32, 64 members of V-SAC and DRL-EG on Hopper-v5 and
Ant-v5 (paper hyperparameters, batch 256 per member, one gradient step per env step), env
steps per second summed over the members, the GPU memory, where a batched step's time goes,
one run (a batch of one) on the GPU beside it, and the projected wall time of
``--profile paper`` Fig. 3 and Fig. 4 from the measured rates.

Each measurement trains from scratch: ``--warmup`` steps from the initial policy (the
harness's ``learning_starts``, 1000), then ``--steps`` timed steps with updates. Results go
to ``--out`` as JSON, written after each measurement so that a cut-off run keeps what it
finished.

    python benchmarks/batched.py --cpu
    python benchmarks/batched.py --cpu --processes 1 --steps 20 --warmup 20   # a smoke run
    python benchmarks/batched.py --update-precision --out reports/bench/bf16_products.json
    python benchmarks/batched.py --cpu --rlfd-cpu --out reports/bench/batched_cpu.json
    python benchmarks/batched.py --gpu --out reports/bench/batched_gpu.json
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from baselines.common.context import BatchContext, TrainContext  # noqa: E402
from baselines.common.stacked import StackedReplay  # noqa: E402
from baselines.offpolicy import seed_device_stream  # noqa: E402
from baselines.registry import batched_trainer, get_algorithm  # noqa: E402
from baselines.sac import SACAgent  # noqa: E402
from envs import env_spec  # noqa: E402

WARMUP = 1000  # env steps before the first update (the default; --warmup)
HUGE = 10**9  # an evaluation interval no bench run reaches


class StepClock:
    """Counts env steps (summed over members) and times the steps after the warm-up, up to
    the one before the last (the last is followed by the final evaluation)."""

    def __init__(self, members: int, warmup: int, total: int):
        self.members, self.warmup, self.total = members, warmup, total
        self.steps = 0
        self.start: float | None = None
        self.end: float | None = None
        self.start_steps = self.end_steps = 0

    def __call__(self, n: int) -> None:
        self.steps += n
        if self.start is None and self.steps >= (self.warmup + 1) * self.members:
            self.start, self.start_steps = time.perf_counter(), self.steps
        if self.end is None and self.steps >= (self.total - 1) * self.members:
            self.end, self.end_steps = time.perf_counter(), self.steps

    def rate(self) -> float:
        return round((self.end_steps - self.start_steps) / (self.end - self.start), 1)


FIG3_PROJECTION = "fig3 batched part (sac, drl-eg, drl-eg-gmm; 4 MuJoCo envs x 5 seeds x 1M) hours"  # noqa: E501


def demos_of(env_id: str):
    from replicate.demos import default_demo_path, load_demos

    return load_demos(default_demo_path(env_id), env_id)


def batched_rate(
    algo: str,
    env_id: str,
    members: int,
    steps: int,
    device: str,
    env_workers: int,
    guide_threshold: float | None = None,
    warmup: int = WARMUP,
) -> dict:
    """Train ``members`` seeds of ``algo`` through its registered batch trainer for
    ``warmup`` + ``steps`` steps; summed env steps/s over the timed steps."""
    algorithm = get_algorithm(algo)
    overrides: dict = {"learning_starts": warmup}
    if guide_threshold is not None:
        overrides["guide_threshold"] = guide_threshold
    configs = [algorithm.make_config(overrides) for _ in range(members)]
    demos = demos_of(env_id) if algorithm.needs_demos else None
    total = warmup + steps
    contexts = [
        TrainContext(
            env_id=env_id,
            seed=seed,
            total_steps=total,
            eval_interval=HUGE,
            eval_episodes=1,
            demos=demos,
        )
        for seed in range(members)
    ]
    clock = StepClock(members, warmup, total)
    bctx = BatchContext(contexts, device=device, env_workers=env_workers, on_steps=clock)
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    started = time.perf_counter()
    algorithm.train_batch(bctx, configs)
    ended = time.perf_counter()
    result = {
        "algo": algo,
        "env": env_id,
        "members": members,
        "device": device,
        "env_workers": env_workers,
        "timed_steps_per_member": steps,
        "env_steps_per_s": clock.rate(),
        "wall_s": round(ended - started, 1),
    }
    if device == "cuda":
        result["gpu_memory_gib"] = round(torch.cuda.max_memory_allocated() / 2**30, 3)
    return result


def one_run_rate(algo: str, env_id: str, steps: int, device: str, warmup: int = WARMUP) -> dict:
    """One run as the runner trains it alone (``Algorithm.train``: a seed batch of one), the
    reference the batches are compared with."""
    algorithm = get_algorithm(algo)
    demos = demos_of(env_id) if algorithm.needs_demos else None
    clock = StepClock(1, warmup, warmup + steps)
    ctx = TrainContext(
        env_id=env_id,
        seed=0,
        total_steps=warmup + steps,
        eval_interval=HUGE,
        eval_episodes=1,
        demos=demos,
        on_steps=clock,
        device=device,
    )
    algorithm.train(ctx, algorithm.make_config({"learning_starts": warmup}))
    return {
        "algo": algo,
        "env": env_id,
        "members": 1,
        "device": device,
        "path": "one run",
        "env_steps_per_s": clock.rate(),
    }


def _concurrent_member(job: tuple) -> None:
    algo, env_id, members, steps, env_workers, barrier, device, results = job
    clock_box: dict = {}
    original = StepClock.__call__

    def tick(self: StepClock, n: int) -> None:  # keep the clock for its wall-clock times
        original(self, n)
        clock_box["clock"] = self

    StepClock.__call__ = tick  # type: ignore[method-assign]
    barrier.wait()
    result = batched_rate(algo, env_id, members, steps, device, env_workers)
    clock = clock_box["clock"]
    offset = time.time() - time.perf_counter()
    result.update(
        start=clock.start + offset,
        end=clock.end + offset,
        timed=clock.end_steps - clock.start_steps,
    )
    results.put(result)


def concurrent_batches(
    algo: str,
    env_id: str,
    members: int,
    processes: int,
    steps: int,
    env_workers: int,
    device: str = "cuda",
) -> dict:
    """``processes`` batches of ``members`` at once on one GPU (what a grid's workers do):
    env steps/s summed over all of them, over the union of their timed windows."""
    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(processes), ctx.Queue()
    procs = [
        ctx.Process(
            target=_concurrent_member,
            args=((algo, env_id, members, steps, env_workers, barrier, device, results),),
        )
        for _ in range(processes)
    ]
    for proc in procs:
        proc.start()
    parts = [results.get() for _ in procs]
    for proc in procs:
        proc.join()
    window = max(p["end"] for p in parts) - min(p["start"] for p in parts)
    return {
        "algo": algo,
        "env": env_id,
        "members per process": members,
        "processes": processes,
        "env_workers per process": env_workers,
        "env_steps_per_s": round(sum(p["timed"] for p in parts) / window, 1),
        "each": [p["env_steps_per_s"] for p in parts],
    }


def step_time_split(
    env_id: str, members: int, device: str, env_workers: int, calls: int = 300
) -> dict[str, float]:
    """Milliseconds per batched step in each part, each timed alone with the device
    synchronised: the policy's action, the env step, the replay write, the update."""
    from envs.vector import EnvBatch

    config = get_algorithm("sac").make_config({})
    contexts = [
        TrainContext(env_id=env_id, seed=s, total_steps=10**6, eval_interval=HUGE, eval_episodes=1)
        for s in range(members)
    ]
    bctx = BatchContext(contexts, device=device, env_workers=env_workers)
    agent = SACAgent(bctx.seeds, env_id, config, device, bctx.cuda_graphs)
    seed_device_stream(bctx)
    spec = env_spec(env_id)
    agent.buffer = StackedReplay(members, spec.obs_dim, spec.act_dim, 10_000, agent.device)
    rngs = [np.random.default_rng(s) for s in range(members)]
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    with EnvBatch(env_id, list(range(members)), env_workers) as envs:
        obs = envs.reset(seeds=list(range(members)))
        timings: dict[str, float] = {}

        def timed(name: str, fn) -> object:
            sync()
            start = time.perf_counter()
            out = fn()
            sync()
            timings[name] = timings.get(name, 0.0) + time.perf_counter() - start
            return out

        for i in range(calls + 10):
            if i == 10:
                timings = {}
            actions = timed("policy action", lambda: agent.act(obs))
            result = timed("env step", lambda: envs.step(actions))
            timed(
                "replay write",
                lambda: agent.buffer.add(
                    obs, actions, result.rewards, result.next_obs, result.terminated
                ),
            )
            obs = result.obs
            timed("gradient step", lambda: agent.update(rngs))
    return {name: round(1000 * seconds / calls, 3) for name, seconds in timings.items()}


def update_precision(calls: int = 50) -> dict[str, float]:
    """Milliseconds per V-SAC update on one thread, for one member and a stack of 3 (a CPU
    core's batch): fp32, bf16 autocast (one member), and fp32 whose products round their
    inputs to bf16 and accumulate in fp32 (oneDNN's bf16 math mode, which runs the products
    on AMX where the CPU has it; ``torch.backends.mkldnn.matmul.fp32_precision``)."""
    from baselines.common.buffer import Batch

    torch.set_num_threads(1)
    matmul = torch.backends.mkldnn.matmul
    default_precision = matmul.fp32_precision
    out = {}
    for members in (1, 3):
        agent = SACAgent(list(range(members)), "Hopper-v5", get_algorithm("sac").make_config({}))
        g = torch.Generator().manual_seed(0)
        batch = Batch(
            torch.randn(members, 256, 11, generator=g),
            torch.rand(members, 256, 3, generator=g),
            torch.randn(members, 256, generator=g),
            torch.randn(members, 256, 11, generator=g),
            torch.zeros(members, 256),
        )
        noise = torch.randn(members, 256, 3, generator=g)
        modes = [("fp32", False, "ieee"), ("fp32, bf16 products", False, "bf16")]
        if members == 1:
            modes.insert(1, ("bf16 autocast", True, "ieee"))
        for name, autocast, precision in modes:
            matmul.fp32_precision = precision
            try:
                for _ in range(5):
                    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
                        agent.gradient_step(batch, noise)
                start = time.perf_counter()
                for _ in range(calls):
                    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
                        agent.gradient_step(batch, noise)
            finally:
                matmul.fp32_precision = default_precision
            out[f"{name} N={members}"] = round(1000 * (time.perf_counter() - start) / calls, 3)
        out[f"bf16 products / fp32 N={members}"] = round(
            out[f"fp32, bf16 products N={members}"] / out[f"fp32 N={members}"], 3
        )
    out["bf16 autocast / fp32 N=1"] = round(out["bf16 autocast N=1"] / out["fp32 N=1"], 3)
    return out


def registered_batch_rate(
    algo: str, env_id: str, members: int, steps: int, warmup: int = WARMUP
) -> float:
    """``members`` seeds of ``algo`` through its registered batched trainer on one CPU
    thread: summed env steps/s over the timed steps."""
    torch.set_num_threads(1)
    algorithm = get_algorithm(algo)
    configs = [algorithm.make_config({"learning_starts": warmup}) for _ in range(members)]
    demos = demos_of(env_id) if algorithm.needs_demos else None
    total = warmup + steps
    contexts = [
        TrainContext(
            env_id=env_id,
            seed=seed,
            total_steps=total,
            eval_interval=HUGE,
            eval_episodes=1,
            demos=demos,
        )
        for seed in range(members)
    ]
    clock = StepClock(members, warmup, total)
    batched_trainer(algo)(BatchContext(contexts, on_steps=clock), configs)
    return clock.rate()


RLFD_CPU_ENV = "dm_control/cartpole-swingup_sparse-v0"


def rlfd_cpu_section(steps: int, write, warmup: int = WARMUP) -> None:
    """IBRL and RLPD (the comparison's learners with a batched trainer beside SAC and
    DRL-EG) on one thread: a batch of 5, the comparison's seeds, against one run (a batch
    of one), env steps/s summed over the members."""
    for algo in ("ibrl", "rlpd"):
        torch.set_num_threads(1)
        one = one_run_rate(algo, RLFD_CPU_ENV, steps, "cpu", warmup)["env_steps_per_s"]
        write("rlfd cpu", {f"{algo} one run": round(one, 1)})
        rate = registered_batch_rate(algo, RLFD_CPU_ENV, 5, steps, warmup)
        write(
            "rlfd cpu",
            {
                f"{algo} batched N=5": round(rate, 1),
                f"{algo} batched N=5 / one run": round(rate / one, 3),
            },
        )


def _cpu_process(job: tuple[int, int, int]) -> float:
    members, steps, warmup = job
    torch.set_num_threads(1)
    return batched_rate("sac", "Hopper-v5", members, steps, "cpu", 0, warmup=warmup)[
        "env_steps_per_s"
    ]


def _cpu_one_run(job: tuple[int, int]) -> float:
    steps, warmup = job
    torch.set_num_threads(1)
    return one_run_rate("sac", "Hopper-v5", steps, "cpu", warmup)["env_steps_per_s"]


def cpu_section(steps: int, write, warmup: int = WARMUP, processes: int | None = None) -> None:
    """Per machine: one process per core (or ``processes``), each a batch of N, against one
    run per process. N = 1 is the one run again, through ``train_batch``: its ratio is the
    bench's noise."""
    cores = processes or os.cpu_count() or 1
    ctx = mp.get_context("spawn")
    with ctx.Pool(cores) as pool:
        one = sum(pool.map(_cpu_one_run, [(steps, warmup)] * cores))
        write("cpu", {"machine one run per process": round(one, 1)})
        for members in (1, 2, 4, 8):
            timed = max(min(steps, 200), steps // members)
            rate = sum(pool.map(_cpu_process, [(members, timed, warmup)] * cores))
            write(
                "cpu",
                {
                    f"machine batched N={members} per process": round(rate, 1),
                    f"batched N={members} / one run per process": round(rate / one, 3),
                },
            )
    write("cpu", {"update ms": update_precision()})


# --profile paper: off-policy runs that the batched trainer trains (env steps).
PAPER_ENVS = ("Hopper-v5", "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")


def gpu_section(steps: int, write, env_workers: int, warmup: int = WARMUP) -> None:
    rates: dict[tuple[str, str, int], float] = {}
    for env_id in ("Hopper-v5", "Ant-v5"):
        spec = env_spec(env_id)
        per_member = StackedReplay.bytes_per_member(spec.obs_dim, spec.act_dim, 1_000_000)
        write("replay_memory_at_1M", {f"{env_id} GiB per member": round(per_member / 2**30, 3)})
    for env_id, sizes in (("Hopper-v5", (8, 16, 32, 64)), ("Ant-v5", (8, 16, 32, 64))):
        for algo in ("sac", "drl-eg"):
            for members in sizes:
                try:
                    result = batched_rate(
                        algo, env_id, members, steps, "cuda", env_workers, warmup=warmup
                    )
                except Exception:
                    write("gpu_errors", {f"{algo} {env_id} N={members}": traceback.format_exc()})
                    continue
                rates[(algo, env_id, members)] = result["env_steps_per_s"]
                write("gpu_batched", {f"{algo} {env_id} N={members}": result})
    for env_id in ("Hopper-v5", "Ant-v5"):
        try:
            one = one_run_rate("sac", env_id, steps, "cuda", warmup)
            write("gpu_one_run", {f"sac {env_id}": one})
        except Exception:
            write("gpu_errors", {f"one run {env_id}": traceback.format_exc()})
    try:
        write(
            "gpu_step_split_ms",
            {"sac Hopper-v5 N=64": step_time_split("Hopper-v5", 64, "cuda", env_workers)},
        )
    except Exception:
        write("gpu_errors", {"split": traceback.format_exc()})
    # Projection: Hopper's rate stands for Walker2d and HalfCheetah (same sizes within 2x),
    # Ant's for Ant; the best measured N of each.
    best = {}
    for (algo, env_id, members), rate in rates.items():
        best[(algo, env_id)] = max(best.get((algo, env_id), 0.0), rate)
    if best:

        def rate_of(algo: str, env_id: str) -> float:
            source = "Ant-v5" if env_id == "Ant-v5" else "Hopper-v5"
            return best.get((algo, source)) or best.get(("sac", source), float("nan"))

        fig3 = sum(
            5 * 1_000_000 / rate_of(a, e) for e in PAPER_ENVS for a in ("sac", "drl-eg", "drl-eg")
        )  # drl-eg-gmm costs about drl-eg
        fig4 = sum(4 * 1_000_000 / rate_of(a, "Ant-v5") for a in ("sac", "drl-eg"))
        write(
            "projection",
            {
                FIG3_PROJECTION: round(fig3 / 3600, 2),
                "fig4 (Ant, sac + drl-eg, 4 seeds x 1M) hours": round(fig4 / 3600, 2),
                "assumes": "each cell's batch at the best measured summed rate, cells one after "
                "another; DDPGfD, PPO and PPO+BC (one run per process on the cores) "
                "are not in these hours",
            },
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cpu", action="store_true", help="the CPU section")
    parser.add_argument("--gpu", action="store_true", help="the GPU section")
    parser.add_argument(
        "--rlfd-cpu",
        action="store_true",
        help="IBRL and RLPD, batch of 5 against one run, on one CPU thread",
    )
    parser.add_argument(
        "--update-precision",
        action="store_true",
        help="only the CPU section's update timings (fp32, bf16 autocast, bf16 products)",
    )
    parser.add_argument(
        "--steps", type=int, default=1000, help="timed env steps per member after the warm-up"
    )
    parser.add_argument(
        "--warmup",
        type=int,
        default=WARMUP,
        help="env steps from the initial policy before the first update (learning_starts)",
    )
    parser.add_argument(
        "--processes", type=int, default=None, help="CPU section: processes (default: one per core)"
    )
    parser.add_argument("--env-workers", type=int, default=max(0, (os.cpu_count() or 1) - 2))
    parser.add_argument("--out", type=Path, default=Path("reports/bench/batched.json"))
    args = parser.parse_args()
    results: dict = {
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "torch": torch.__version__,
            "gpu": torch.cuda.get_device_name() if torch.cuda.is_available() else None,
        },
        "command": " ".join(sys.argv),
        "steps": args.steps,
        "warmup": args.warmup,
    }

    def write(section: str, values: dict) -> None:
        results.setdefault(section, {}).update(values)
        print(json.dumps({section: values}), flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1) + "\n")

    if args.steps < 3 or args.warmup < 1:
        parser.error("--steps must be >= 3 and --warmup >= 1")
    if args.gpu:
        gpu_section(args.steps, write, args.env_workers, args.warmup)
    if args.rlfd_cpu:
        rlfd_cpu_section(args.steps, write, args.warmup)
    if args.cpu:
        cpu_section(args.steps, write, args.warmup, args.processes)
    elif args.update_precision:
        write("cpu", {"update ms": update_precision()})


if __name__ == "__main__":
    main()
