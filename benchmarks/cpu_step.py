"""One CPU gradient step of the off-policy trainer: where its time goes, and what
``torch.compile`` (inductor) makes of it. Part of ``nox -s bench``; it adds two sections to
the bench JSON (``--out``, default ``reports/bench/bench.json``; its other keys are kept):

- ``cpu_step_profile``: one V-SAC update (Hopper-v5, one member, paper sizes, one torch
  thread; minibatch sampling included) under ``torch.profiler``, its time split into
  matrix products, other kernels (elementwise, reductions, copies), the optimisers (Adam
  and the target network's Polyak step, their Python included), the autograd engine, and
  the rest (Python and dispatch between operators, and the profiler's own cost), beside
  the time its FLOPs would take at the matrix-product rate measured here.
- ``compiled_step``: for N = 1, 4, 8 members on Hopper-v5 and Ant-v5, the member-axis
  gradient step compiled (``torch.compile`` of the agent's ``gradient_step``; with
  ``compiled-autograd`` the backward passes are traced too) against eager: compile time
  (cold inductor cache, then warm), agreement with eager after one and after several steps,
  determinism of the compiled step, time per update; and, where the first step agrees with
  eager, short V-SAC and DRL-EG runs with either step in the same process (eager,
  compiled, compiled, eager), whose whole-run speed-up spreads the cold compile time over
  a 200k-step run. A setting pays where a whole run is at least 1.2x faster and its first
  step agrees with eager.

Every (env, N, variant) compiles in a fresh process with a cache of its own, so no compile
is paid by or hidden in another.

    python benchmarks/cpu_step.py
    python benchmarks/cpu_step.py --envs Hopper-v5 --members 1 --variants default \\
        --calls 10 --rounds 1 --run-steps 20 --run-warmup 20 --out /tmp/step.json  # smoke
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from baselines.common.buffer import Batch  # noqa: E402
from baselines.contract import agent_state, load_agent_state  # noqa: E402
from baselines.sac import SACAgent, SACConfig  # noqa: E402
from baselines.training_loop import action_space  # noqa: E402
from benchmarks.batched import batched_rate  # noqa: E402
from benchmarks.bench_measure import flops_per_call, gemm_gflops  # noqa: E402

RUN_STEPS = 200_000  # the run a compile is paid once for (the reduced profile's budget)
PAYS = 1.2  # whole-run speed-up at which compiling is worth offering
VARIANTS = ("default", "compiled-autograd")
# DRL-EG's gradient step is V-SAC's (its agent is SACAgent): one step measurement serves
# both, and their whole runs differ only in what surrounds the step
ALGOS = ("sac", "drl-eg")


def sac_agent(env_id: str, members: int, replay_rows: int = 5000) -> tuple[SACAgent, list]:
    """A V-SAC agent of ``members`` seeds at paper sizes, its replay filled with
    ``replay_rows`` random transitions, and the members' replay generators."""
    obs_dim, _, _, _ = action_space(env_id)
    agent = SACAgent(list(range(members)), env_id, SACConfig(), cuda_graphs=False)
    agent.buffer = agent.make_replay(members, obs_dim, 2 * replay_rows)
    data = agent.buffer.data[:, :replay_rows]
    data.normal_(generator=torch.Generator().manual_seed(0))
    data[..., -1] = 0.0  # not terminated
    agent.buffer.size = agent.buffer.position = replay_rows
    return agent, [np.random.default_rng(seed) for seed in range(members)]


def ms_per_call(fn: Any, calls: int, warmup: int = 5) -> float:
    for _ in range(warmup):
        fn()
    start = time.perf_counter()
    for _ in range(calls):
        fn()
    return 1e3 * (time.perf_counter() - start) / calls


# --- where one step's time goes ---------------------------------------------------------

MATRIX_PRODUCTS = {"aten::mm", "aten::bmm", "aten::addmm", "aten::baddbmm", "aten::addbmm"}


def _category(event: Any) -> str:
    """An event's share of its own time: optimiser work wherever it runs under an optimiser
    step or a foreach (Polyak) call, then by what the operator is."""
    node = event
    while node is not None:
        if node.name.startswith("Optimizer.") or node.name.startswith("aten::_foreach_"):
            return "optimisers"
        node = node.cpu_parent
    if event.name in MATRIX_PRODUCTS:
        return "matrix products"
    if event.name.startswith("aten::"):
        return "other kernels"
    return "autograd engine"


def step_profile(env_id: str = "Hopper-v5", members: int = 1, calls: int = 100) -> dict:
    """Where one eager V-SAC update's time goes (see the module's docstring)."""
    from torch.profiler import ProfilerActivity, profile

    torch.set_num_threads(1)
    agent, rngs = sac_agent(env_id, members)

    def update() -> None:
        agent.update(rngs)

    step_ms = ms_per_call(update, calls, warmup=20)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        start = time.perf_counter()
        for _ in range(calls):
            update()
        profiled_ms = 1e3 * (time.perf_counter() - start) / calls
    spent = dict.fromkeys(
        ["matrix products", "other kernels", "optimisers", "autograd engine"], 0.0
    )
    for event in prof.events():
        spent[_category(event)] += event.self_cpu_time_total / 1e3 / calls
    spent["Python, dispatch and profiler between operators"] = max(
        0.0, profiled_ms - sum(spent.values())
    )
    gflops = gemm_gflops()
    mflop = flops_per_call(update) / 1e6
    return {
        "env": env_id,
        "members": members,
        "step_ms": round(step_ms, 3),
        "profiled_step_ms": round(profiled_ms, 3),
        "ms": {k: round(v, 3) for k, v in spent.items()},
        "share": {k: round(v / profiled_ms, 3) for k, v in spent.items()},
        "gemm_256_gflops": round(gflops, 1),
        "step_mflop": round(mflop, 1),
        "flop_ms_at_gemm_rate": round(mflop / gflops, 3),
        "step / flop time": round(step_ms / (mflop / gflops), 3),
    }


# --- the compiled step -------------------------------------------------------------------


def _inputs(agent: SACAgent, count: int) -> list[tuple[Batch, torch.Tensor]]:
    """Minibatches and noise as an update draws them (views of the gathered rows, which the
    compiled step is specialised to), from streams of their own."""
    rngs = [np.random.default_rng(100 + k) for k in range(agent.members)]
    g = torch.Generator().manual_seed(1)
    shape = (agent.members, agent.batch_size, agent.act_dim)
    return [
        (agent.buffer.sample(agent.batch_size, rngs), torch.randn(shape, generator=g))
        for _ in range(count)
    ]


def _largest_gap(a: SACAgent, b: SACAgent) -> float:
    return max(
        float((p - q).detach().abs().max())
        for name in ("policy", "critics", "v")
        for p, q in zip(getattr(a, name).parameters(), getattr(b, name).parameters())
    )


AGREES = 1e-4  # the largest difference from eager after one step of a correct compile


def compile_measurement(
    env_id: str,
    members: int,
    variant: str,
    calls: int,
    rounds: int,
    run_steps: int,
    run_warmup: int,
    agreement_steps: int = 5,
) -> dict:
    """In a fresh process (``_in_child``): the compiled against the eager step, and, where
    the compiled step agrees with eager, short V-SAC and DRL-EG runs with either."""
    import torch._dynamo

    torch.set_num_threads(1)
    # every new agent is a new guard (its modules), so allow more than the default recompiles
    for limit in ("recompile_limit", "cache_size_limit"):
        if hasattr(torch._dynamo.config, limit):
            setattr(torch._dynamo.config, limit, 64)
    if variant == "compiled-autograd":
        torch._dynamo.config.compiled_autograd = True
        torch._dynamo.config.trace_autograd_ops = True
    eager, rngs = sac_agent(env_id, members)
    compiled, compiled_rngs = sac_agent(env_id, members)  # the same seeds: the same weights
    start_state = agent_state(compiled)
    compiled.gradient_step = torch.compile(compiled.gradient_step)
    inputs = _inputs(eager, agreement_steps)

    began = time.perf_counter()
    first = compiled.gradient_step(*inputs[0])  # compiles, then runs one step
    compile_s = time.perf_counter() - began
    reference = eager.gradient_step(*inputs[0])
    first_gap = max(
        _largest_gap(eager, compiled),
        *(float((first[k] - reference[k]).abs().max()) for k in reference),
    )
    losses = [first]
    for batch, noise in inputs[1:]:
        losses.append({k: v.clone() for k, v in compiled.gradient_step(batch, noise).items()})
        eager.gradient_step(batch, noise)
    gap = _largest_gap(eager, compiled)
    bitwise = gap == 0.0 and all(
        torch.equal(a, b) for a, b in zip(compiled.policy.parameters(), eager.policy.parameters())
    )
    load_agent_state(compiled, start_state)  # again from the start: the same numbers?
    again = [compiled.gradient_step(b, n) for b, n in inputs]
    deterministic = all(
        torch.equal(losses[i][k], again[i][k]) for i in range(len(inputs)) for k in losses[i]
    )

    eager_ms, compiled_ms = [], []
    for _ in range(rounds):  # interleaved: a slow spell hits both
        eager_ms.append(ms_per_call(lambda: eager.update(rngs), calls))
        compiled_ms.append(ms_per_call(lambda: compiled.update(compiled_rngs), calls))

    runs = {}
    if first_gap <= AGREES:  # a step that computes something else is not worth a run
        eager_step = SACAgent.gradient_step
        for algo in ALGOS:  # eager, compiled, compiled, eager: a drift in speed hits both
            rates: dict[str, list[float]] = {"eager": [], "compiled": []}
            for kind in ("eager", "compiled", "compiled", "eager"):
                # the trainer builds its own agent: compile the step of every SACAgent; its
                # first update (before the clock starts) compiles it for that agent
                if kind == "compiled":
                    SACAgent.gradient_step = torch.compile(eager_step)
                try:
                    rate = batched_rate(
                        algo, env_id, members, run_steps, "cpu", 0, warmup=run_warmup
                    )
                finally:
                    SACAgent.gradient_step = eager_step
                rates[kind].append(rate["env_steps_per_s"])
            eager_rate, compiled_rate = (statistics.mean(rates[k]) for k in rates)
            runs[algo] = {
                "eager_env_steps_per_s": rates["eager"],
                "compiled_env_steps_per_s": rates["compiled"],
                "whole_run_speedup": round(
                    whole_run_speedup(members / eager_rate, members / compiled_rate, compile_s),
                    3,
                ),
            }

    # last, since a reset drops every compiled step: a second compile of the step hits the
    # cache the first one filled (what a grid's later runs on one machine pay)
    warm, _ = sac_agent(env_id, members)
    torch._dynamo.reset()
    warm.gradient_step = torch.compile(warm.gradient_step)
    began = time.perf_counter()
    warm.gradient_step(*inputs[0])
    warm_compile_s = time.perf_counter() - began

    return {
        "env": env_id,
        "members": members,
        "variant": variant,
        "compile_s": round(compile_s, 2),
        "warm_compile_s": round(warm_compile_s, 2),
        "first_step_max_abs_difference": first_gap,
        f"max_abs_difference_after_{agreement_steps}_steps": gap,
        "bit_identical_to_eager": bitwise,
        "deterministic": deterministic,
        "eager_update_ms": round(statistics.median(eager_ms), 3),
        "compiled_update_ms": round(statistics.median(compiled_ms), 3),
        "update_speedup": round(statistics.median(eager_ms) / statistics.median(compiled_ms), 3),
        "runs": runs,
    }


def _in_child(job: tuple) -> dict:
    """One measurement with an inductor cache of its own (a cold first compile)."""
    *args, cache = job
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = cache
    return compile_measurement(*args)


def whole_run_speedup(eager_step_s: float, compiled_step_s: float, compile_s: float) -> float:
    """A ``RUN_STEPS``-step run's speed-up from compiling: steps of ``compiled_step_s``
    instead of ``eager_step_s`` (env, acting and update), the compile paid once."""
    return eager_step_s / (compiled_step_s + compile_s / RUN_STEPS)


def decision(rows: list[dict]) -> dict:
    """Pays where a whole run is >= ``PAYS`` faster and the first step agrees with eager."""
    paying = [r for r in rows if r["pays"]]

    def name(r: dict) -> str:
        return f"{r['algo']} {r['env']} N={r['members']} {r['variant']}"

    measured = [r for r in rows if r["whole_run_speedup"] is not None]
    out = {
        "threshold": PAYS,
        "pays": bool(rows) and len(paying) == len(rows),
        "pays_for": [name(r) for r in paying],
        "not_agreeing_with_eager": [name(r) for r in rows if not r["first_step_agrees"]],
        "offer": "offer --compile where it pays" if paying else "not offered: it does not pay",
    }
    if measured:
        best = max(measured, key=lambda r: r["whole_run_speedup"])
        worst = min(measured, key=lambda r: r["whole_run_speedup"])
        out["best"] = {"where": name(best), "whole_run_speedup": best["whole_run_speedup"]}
        out["worst"] = {"where": name(worst), "whole_run_speedup": worst["whole_run_speedup"]}
    return out


def compiled_step(
    envs: list[str],
    members: list[int],
    variants: list[str],
    calls: int,
    rounds: int,
    run_steps: int,
    run_warmup: int,
) -> dict:
    """Every (env, N, variant) measured in a process of its own, and the decision."""
    steps = []
    spawn = mp.get_context("spawn")
    for env_id in envs:
        for n in members:
            for variant in variants:
                with tempfile.TemporaryDirectory(prefix="inductor-") as cache:
                    with spawn.Pool(1) as pool:
                        job = (env_id, n, variant, calls, rounds, run_steps, run_warmup, cache)
                        steps.append(pool.apply(_in_child, (job,)))
                print(f"  compiled step: {json.dumps(steps[-1])}", flush=True)
    rows = []
    for m in steps:
        agrees = m["first_step_max_abs_difference"] <= AGREES
        for algo in ALGOS:
            run = m["runs"].get(algo, {})
            speedup = run.get("whole_run_speedup")
            rows.append(
                {
                    "algo": algo,
                    "env": m["env"],
                    "members": m["members"],
                    "variant": m["variant"],
                    **run,
                    "whole_run_speedup": speedup,
                    "first_step_agrees": agrees,
                    "pays": agrees and speedup is not None and speedup >= PAYS,
                }
            )
    return {
        "run_steps_amortised_over": RUN_STEPS,
        "steps": steps,
        "whole_runs": rows,
        "decision": decision(rows),
    }


def write_sections(out: Path, sections: dict[str, Any]) -> None:
    """Add ``sections`` to the JSON file ``out``, keeping its other keys."""
    data: dict[str, Any] = {}
    if out.is_file():
        try:
            data = json.loads(out.read_text())
        except json.JSONDecodeError:
            data = {}
    data.update(sections)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=2) + "\n")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "reports/bench/bench.json")
    parser.add_argument("--envs", nargs="+", default=["Hopper-v5", "Ant-v5"])
    parser.add_argument("--members", nargs="+", type=int, default=[1, 4, 8])
    parser.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS))
    parser.add_argument("--calls", type=int, default=100, help="updates per timing round")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved timing rounds")
    parser.add_argument("--run-steps", type=int, default=150, help="timed steps per run")
    parser.add_argument("--run-warmup", type=int, default=1000, help="steps before updates")
    parser.add_argument("--profile-calls", type=int, default=100)
    args = parser.parse_args(argv)
    began = time.perf_counter()
    print("profiling one CPU gradient step ...", flush=True)
    profile = step_profile(calls=args.profile_calls)
    print(json.dumps(profile, indent=1), flush=True)
    print("compiling the gradient step ...", flush=True)
    compiled = compiled_step(
        args.envs,
        args.members,
        args.variants,
        args.calls,
        args.rounds,
        args.run_steps,
        args.run_warmup,
    )
    compiled["machine"] = {"platform": platform.platform(), "torch": torch.__version__}
    compiled["command"] = " ".join(["benchmarks/cpu_step.py", *(argv or sys.argv[1:])])
    compiled["wall_s"] = round(time.perf_counter() - began, 1)
    write_sections(args.out, {"cpu_step_profile": profile, "compiled_step": compiled})
    print(json.dumps(compiled["decision"], indent=1))
    print(f"written: {args.out} ({compiled['wall_s']:.0f} s)")


if __name__ == "__main__":
    main()
