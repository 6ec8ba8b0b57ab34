"""Throughput benchmark: the harness against Stable-Baselines3 and against the hardware floor.

Every number is measured in this one run on this machine, and every target is a ratio of two
such numbers, so the table means the same on a laptop and on a server. Run it with
``nox -s bench`` (which installs stable-baselines3, a bench-only dependency); it prints the
table and writes ``reports/bench/bench.json``.

Measurements (Hopper-v5, one torch thread per process, batch 256, 2x256 networks, one
gradient step per env step after 1000 steps from the initial policy):

- env: raw Gymnasium env against the harness's adapter, random actions;
- floor: a bare twin-Q, auto-alpha SAC update in plain PyTorch, the least any SAC can cost;
- the harness's twin-Q, learned-temperature SAC (``sac-twin-q``, like for like with SB3's SAC)
  and the paper's V-network SAC (``sac``): their updates alone and their training loops;
- Stable-Baselines3 SAC with the same hyperparameters;
- DRL-EG's guidance: what D(s) and G(s) add to an env step, with 1000 and with 1,000,000
  demonstrations, and whole DRL-EG runs beside SAC runs;
- the harness's PPO against SB3's PPO (2048-step rollouts, 10 epochs, minibatch 64, 2x64);
- the machine: a four-seed job on one process per core, harness and SB3;
- where a twin-Q SAC run's time goes (env, policy action, replay, gradient steps).

With a CUDA GPU the GPU path is measured too (``--gpu-only`` measures it alone, into
``reports/bench/bench_gpu.json``): graphed against eager updates, whole runs against SB3 on
the same GPU and on one core, and a job of two seeds per core with some processes on the GPU.

Whole-run speeds move by 5-15% between repetitions on a shared machine, so each is the
median of ``--repeats`` runs, interleaved so that a slow spell hits every contender.
"""

from __future__ import annotations

import argparse
import functools
import json
import multiprocessing as mp
import os
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from baselines.common.device import worker_devices

ENV_ID = "Hopper-v5"
GPU_WORKER_COUNTS = (1, 2, 4, None)  # processes on the GPU in the machine job (None: all)
WARMUP = 1000  # env steps before the first update, as in the harness's SAC


def env_steps_per_s(make, steps: int) -> float:
    env = make()
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(steps)]
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - start)


def bench_env(steps: int) -> dict[str, float]:
    import gymnasium as gym

    from envs import make_env

    raw, adapter = [], []
    for _ in range(5):  # interleaved, best of five: warm-up and noise hit both alike
        raw.append(env_steps_per_s(lambda: gym.make(ENV_ID), steps))
        adapter.append(env_steps_per_s(lambda: make_env(ENV_ID), steps))
    return {"raw_env_steps_per_s": max(raw), "adapter_env_steps_per_s": max(adapter)}


def make_floor_update(obs_dim: int = 11, act_dim: int = 3) -> Callable[[], None]:
    """One update of a minimal twin-Q, auto-alpha SAC: nothing but the math."""
    from torch import nn

    torch.manual_seed(0)

    def net(inputs: int, outputs: int) -> nn.Module:
        return nn.Sequential(
            nn.Linear(inputs, 256),
            nn.ReLU(),
            nn.Linear(256, 256),
            nn.ReLU(),
            nn.Linear(256, outputs),
        )

    q1, q2 = net(obs_dim + act_dim, 1), net(obs_dim + act_dim, 1)
    q1_t, q2_t = net(obs_dim + act_dim, 1), net(obs_dim + act_dim, 1)
    actor = net(obs_dim, 2 * act_dim)
    log_alpha = torch.zeros(1, requires_grad=True)
    q_opt = torch.optim.Adam([*q1.parameters(), *q2.parameters()], lr=3e-4)
    pi_opt = torch.optim.Adam(actor.parameters(), lr=3e-4)
    a_opt = torch.optim.Adam([log_alpha], lr=3e-4)
    batch = 256
    obs, act = torch.randn(batch, obs_dim), torch.rand(batch, act_dim) * 2 - 1
    rew, nxt, done = torch.randn(batch, 1), torch.randn(batch, obs_dim), torch.zeros(batch, 1)

    def sample(o: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, log_std = actor(o).chunk(2, -1)
        std = log_std.clamp(-20, 2).exp()
        u = mean + std * torch.randn_like(mean)
        a = torch.tanh(u)
        logp = (-0.5 * ((u - mean) / std) ** 2 - std.log()).sum(-1, keepdim=True) - torch.log(
            1 - a.pow(2) + 1e-6
        ).sum(-1, keepdim=True)
        return a, logp

    def update() -> None:
        with torch.no_grad():
            na, nlogp = sample(nxt)
            qn = torch.min(q1_t(torch.cat([nxt, na], -1)), q2_t(torch.cat([nxt, na], -1)))
            y = rew + 0.99 * (1 - done) * (qn - log_alpha.exp() * nlogp)
        sa = torch.cat([obs, act], -1)
        q_loss = ((q1(sa) - y) ** 2).mean() + ((q2(sa) - y) ** 2).mean()
        q_opt.zero_grad()
        q_loss.backward()
        q_opt.step()
        a, logp = sample(obs)
        sa_new = torch.cat([obs, a], -1)
        pi_loss = (log_alpha.exp().detach() * logp - torch.min(q1(sa_new), q2(sa_new))).mean()
        pi_opt.zero_grad()
        pi_loss.backward()
        pi_opt.step()
        alpha_loss = -(log_alpha * (logp.detach() - act_dim)).mean()
        a_opt.zero_grad()
        alpha_loss.backward()
        a_opt.step()
        with torch.no_grad():
            for t, s in zip(
                [*q1_t.parameters(), *q2_t.parameters()],
                [*q1.parameters(), *q2.parameters()],
                strict=True,
            ):
                t.lerp_(s, 0.005)

    return update


def make_harness_update(
    algo: str = "sac", device: str = "cpu", cuda_graphs: bool = True
) -> Callable[[], None]:
    """One update of the harness's SAC (``sac``: the paper's V-network version, or
    ``sac-twin-q``) for one run (a seed batch of one, as the runner trains a run alone) on a
    filled replay, its minibatch sampled as in training. On CUDA the call waits for the GPU
    to finish."""
    from baselines.sac import SACAgent, SACConfig
    from baselines.sac_twin_q import TwinQSACAgent, TwinQSACConfig

    agent_cls, config = (
        (SACAgent, SACConfig()) if algo == "sac" else (TwinQSACAgent, TwinQSACConfig())
    )
    agent = agent_cls([0], ENV_ID, config, device=device, cuda_graphs=cuda_graphs)
    agent.buffer = agent.make_replay(1, 11, 10_000)
    rng = np.random.default_rng(0)
    for _ in range(5000):
        agent.buffer.add(
            rng.normal(size=(1, 11)),
            rng.uniform(-1, 1, (1, 3)),
            np.ones(1),
            rng.normal(size=(1, 11)),
            np.zeros(1),
        )
    rngs = [rng]
    if device == "cpu":
        return lambda: agent.update(rngs)

    def update_and_wait() -> None:
        agent.update(rngs)
        torch.cuda.synchronize()

    return update_and_wait


def seconds_per_call(fn: Callable[[], None], calls: int) -> float:
    for _ in range(20):
        fn()
    start = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - start) / calls


def flops_per_call(fn: Callable[[], None]) -> int:
    """Floating-point operations of one call, forward and backward, as torch counts them."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        fn()
    return counter.get_total_flops()


def gemm_gflops(size: int = 256, calls: int = 2000) -> float:
    """The CPU's matrix-product rate at the update's dominant shape (batch 256, 256 x 256)."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    out = torch.empty(size, size)
    seconds = seconds_per_call(lambda: torch.mm(a, b, out=out), calls)
    return 2 * size**3 / seconds / 1e9


def update_profile(fn: Callable[[], None], calls: int = 200, top: int = 8) -> list[dict]:
    """Where an update's time goes: the operators with the most self CPU time."""
    from torch.profiler import ProfilerActivity, profile

    for _ in range(20):
        fn()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(calls):
            fn()
    events = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)
    total = sum(e.self_cpu_time_total for e in events)
    return [
        {
            "op": e.key,
            "share": round(e.self_cpu_time_total / total, 3),
            "calls_per_update": round(e.count / calls, 1),
        }
        for e in events[:top]
    ]


def ppo_time_split(steps: int = 4096) -> dict[str, float]:
    """Where a harness PPO run's time goes: shares of the run's wall time (cProfile)."""
    import cProfile
    import pstats

    from baselines.common.context import TrainContext
    from baselines.registry import get_algorithm

    algorithm = get_algorithm("ppo")
    ctx = TrainContext(
        env_id=ENV_ID, seed=0, total_steps=steps, eval_interval=10 * steps, eval_episodes=1
    )
    algorithm.train(ctx, algorithm.make_config({}))  # imports and first calls off the clock
    profiler = cProfile.Profile()
    profiler.enable()
    algorithm.train(ctx, algorithm.make_config({}))
    profiler.disable()
    stats = pstats.Stats(profiler).stats  # (file, line, name) -> (cc, nc, tottime, cumtime, ..)
    total = max(cum for _, _, _, cum, _ in stats.values())

    def cumulative(file_part: str, name: str) -> float:
        return sum(
            cum
            for (file, _, fn), (_, _, _, cum, _) in stats.items()
            if file_part in file and fn == name
        )

    split = {
        "env step (MuJoCo and wrappers)": cumulative("envs/__init__", "step"),
        "policy sample per env step": cumulative("baselines/ppo", "sample"),
        "observation normalisation": cumulative("baselines/ppo", "normalize"),
        "backward": cumulative("torch/autograd/graph", "_engine_run_backward"),
        "Adam": cumulative("torch/optim/adam", "step"),
        "gradient clipping": cumulative("torch/nn/utils/clip_grad", "clip_grad_norm_"),
    }
    split["everything else (losses, GAE, the loop)"] = total - sum(split.values())
    return {name: round(seconds / total, 3) for name, seconds in split.items()}


def sac_time_split(algo: str, steps: int, device: str = "cpu") -> dict[str, float]:
    """Where a harness SAC run's time goes: shares of its wall time, from timers wrapped
    around the env step, the policy's action, the replay and the gradient step (on a GPU the
    gradient step is waited for, so that its GPU time is not billed to the next action,
    which would wait for it anyway). Each timer counts its own time only: on CPU the
    replay's sampling, called inside the update, is billed to the replay."""
    from baselines.common.context import TrainContext
    from baselines.common.stacked import StackedReplay
    from baselines.offpolicy import OffPolicyAgent
    from baselines.registry import get_algorithm
    from envs import FlatFloat32Env

    seconds = {
        "env step (MuJoCo and wrappers)": 0.0,
        "policy action per env step": 0.0,
        "replay add and sample": 0.0,
        "gradient steps": 0.0,
    }

    nested: list[float] = []  # per timer running, the time of the timers inside it

    def timed(owner: type, method: str, part: str, wait: bool = False):
        original = owner.__dict__[method]

        def wrapper(*args, **kwargs):
            nested.append(0.0)
            start = time.perf_counter()
            try:
                result = original(*args, **kwargs)
                if wait and device == "cuda":
                    torch.cuda.synchronize()
            finally:
                elapsed = time.perf_counter() - start
                inner = nested.pop()
                seconds[part] += elapsed - inner
                if nested:
                    nested[-1] += elapsed
            return result

        return original, wrapper

    patches = [
        (FlatFloat32Env, "step", "env step (MuJoCo and wrappers)", False),
        (OffPolicyAgent, "act", "policy action per env step", False),
        (StackedReplay, "add", "replay add and sample", False),
        (StackedReplay, "sample", "replay add and sample", False),
        (OffPolicyAgent, "update", "gradient steps", True),
    ]
    originals = []
    for owner, method, part, wait in patches:
        original, wrapper = timed(owner, method, part, wait)
        originals.append((owner, method, original))
        setattr(owner, method, wrapper)
    algorithm = get_algorithm(algo)
    ctx = TrainContext(
        env_id=ENV_ID,
        seed=0,
        total_steps=steps,
        eval_interval=10 * steps,
        eval_episodes=1,
        device=device,
    )
    try:
        start = time.perf_counter()
        algorithm.train(ctx, algorithm.make_config({}))
        total = time.perf_counter() - start
    finally:
        for owner, method, original in originals:
            setattr(owner, method, original)
    seconds["everything else (the loop, evaluations, set-up)"] = total - sum(seconds.values())
    return {name: round(value / total, 3) for name, value in seconds.items()}


def harness_run_steps_per_s(
    algo: str,
    steps: int,
    overrides: dict | None = None,
    demos=None,
    device: str = "cpu",
    cuda_graphs: bool = True,
) -> float:
    """Env steps per second of a whole training run (updates from step 1000 on)."""
    from baselines.common.context import TrainContext
    from baselines.registry import get_algorithm

    algorithm = get_algorithm(algo)
    config = algorithm.make_config(overrides or {})
    ctx = TrainContext(
        env_id=ENV_ID,
        seed=0,
        total_steps=steps,
        eval_interval=10 * steps,
        eval_episodes=1,
        demos=demos,
        device=device,
        cuda_graphs=cuda_graphs,
    )
    start = time.perf_counter()
    algorithm.train(ctx, config)
    return steps / (time.perf_counter() - start)


@functools.lru_cache(maxsize=2)  # built once per size: the 1M set serves two measurements
def hopper_demos(n_pairs: int):
    """The committed Hopper demonstrations, and for more pairs than they hold, copies of their
    states with small noise: a huge demonstration set along the expert's own trajectory."""
    from replicate.demos import Demonstrations, default_demo_path, load_demos

    committed = load_demos(default_demo_path(ENV_ID), ENV_ID)
    rng = np.random.default_rng(0)
    index = np.arange(n_pairs) % len(committed.observations)
    jitter = 0.0 if n_pairs <= len(committed.observations) else 0.01
    observations = committed.observations[index] + rng.normal(
        scale=jitter, size=(n_pairs, committed.observations.shape[1])
    )
    return Demonstrations(
        observations.astype(np.float32), committed.actions[index], {"expert_return_mean": 1e9}
    )


def guidance_cost(n_pairs: int, threshold: float, states: int = 3000) -> dict[str, float]:
    """What DRL-EG adds to an env step: its explorer's choice against SAC's policy action,
    timed on the same states (those an untrained SAC agent visits, early training's case),
    with the gate open. Returns microseconds per step and the seconds the index takes to build."""
    from baselines.drl_eg import DRLEGConfig, GuidedExplorer
    from baselines.sac import SACAgent
    from envs import make_env

    demos = hopper_demos(n_pairs)  # their mean return is huge: the gate stays open
    config = DRLEGConfig(guide_threshold=threshold)
    agent = SACAgent([0], ENV_ID, config)  # one run: a seed batch of one
    low, high = -np.ones(3), np.ones(3)
    start = time.perf_counter()
    explorer = GuidedExplorer(agent, [config], demos, low, high, [0])  # builds the KD-tree
    build_s = time.perf_counter() - start
    env, visited = make_env(ENV_ID, seed=0), []
    obs, _ = env.reset(seed=0)
    for _ in range(states):
        visited.append(obs[None])  # one member's row
        obs, _, terminated, truncated, _ = env.step(agent.act(obs[None])[0])
        if terminated or truncated:
            obs, _ = env.reset()
    guided = 0
    times = {"act": [], "choose": []}
    for _ in range(3):  # interleaved, best of three
        start = time.perf_counter()
        for state in visited:
            agent.act(state)
        times["act"].append(time.perf_counter() - start)
        start = time.perf_counter()
        for state in visited:
            guided += int(explorer.choose(state)[1][0])
        times["choose"].append(time.perf_counter() - start)
    act_us, choose_us = (1e6 * min(times[k]) / len(visited) for k in ("act", "choose"))
    return {
        "index_build_s": build_s,
        "sac_act_us": act_us,
        "drl_eg_choose_us": choose_us,
        "added_us_per_step": choose_us - act_us,
        "guided_fraction": guided / (3 * len(visited)),
    }


def sb3_sac_steps_per_s(steps: int, device: str = "cpu") -> float:
    import gymnasium as gym
    from stable_baselines3 import SAC

    torch.set_num_threads(1)
    model = SAC(
        "MlpPolicy",
        gym.make(ENV_ID),
        learning_rate=3e-4,
        buffer_size=steps,
        learning_starts=WARMUP,
        batch_size=256,
        tau=0.005,
        gamma=0.99,
        train_freq=1,
        gradient_steps=1,
        policy_kwargs={"net_arch": [256, 256]},
        seed=0,
        device=device,
        verbose=0,
    )
    start = time.perf_counter()
    model.learn(total_timesteps=steps)
    return steps / (time.perf_counter() - start)


def sb3_ppo_steps_per_s(steps: int) -> float:
    import gymnasium as gym
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    model = PPO(
        "MlpPolicy",
        gym.make(ENV_ID),
        n_steps=2048,
        batch_size=64,
        n_epochs=10,
        policy_kwargs={"net_arch": [64, 64]},
        seed=0,
        device="cpu",
        verbose=0,
    )
    start = time.perf_counter()
    model.learn(total_timesteps=steps)
    return steps / (time.perf_counter() - start)


_process_device = "cpu"  # a pool process's device, taken from the pool's list at its start


def _start_process(devices) -> None:
    """Pool initializer: take a device, and pay imports and CUDA start-up off the clock."""
    global _process_device
    _process_device = devices.get()
    torch.set_num_threads(1)
    import stable_baselines3  # noqa: F401

    import baselines.sac_twin_q  # noqa: F401

    if _process_device == "cuda":
        torch.zeros(1, device="cuda").sum().item()


def _one_process(job: tuple[str, int]) -> float:
    kind, steps = job
    if kind == "sb3":
        return sb3_sac_steps_per_s(steps, _process_device)
    return harness_run_steps_per_s(kind, steps, device=_process_device)


def machine_steps_per_s(
    kind: str, steps: int, processes: int, runs: int, devices: list[str] | None = None
) -> float:
    """Total env steps per second of a ``runs``-seed SAC job on ``processes`` processes, the
    k-th process on ``devices[k]`` (default: all on the CPU)."""
    context = mp.get_context("spawn")
    slots = context.Queue()
    for device in devices or ["cpu"] * processes:
        slots.put(device)
    with context.Pool(processes, initializer=_start_process, initargs=(slots,)) as pool:
        pool.map(time.sleep, [1.0] * processes, chunksize=1)  # every process started
        start = time.perf_counter()
        pool.map(_one_process, [(kind, steps)] * runs, chunksize=1)
        return runs * steps / (time.perf_counter() - start)


def median_of(repeats: int, measurements: dict[str, Callable[[], float]]) -> dict[str, float]:
    """Each measurement's median over ``repeats`` rounds, the contenders interleaved."""
    values: dict[str, list[float]] = {name: [] for name in measurements}
    for _ in range(repeats):
        for name, measure in measurements.items():
            values[name].append(measure())
            print(f"  {name}: {values[name][-1]:.3f}", flush=True)
    return {name: float(np.median(v)) for name, v in values.items()}


def gpu_measurements(steps: int, repeats: int) -> tuple[dict[str, float], list[tuple]]:
    """The GPU path: graphed against eager updates, whole runs against SB3 on the same GPU and
    against both on this machine's CPU, and a job of two seeds per core with 1, 2, 4 or all
    of its processes on the one GPU."""
    results: dict[str, float] = {}
    cores = os.cpu_count() or 1
    print(f"measuring on {torch.cuda.get_device_name()}: updates ...", flush=True)
    twin_graphed = make_harness_update("sac-twin-q", "cuda", cuda_graphs=True)
    twin_eager = make_harness_update("sac-twin-q", "cuda", cuda_graphs=False)
    v_graphed = make_harness_update("sac", "cuda", cuda_graphs=True)
    results.update(
        median_of(
            repeats,
            {
                "gpu_twin_q_update_graphed_ms": lambda: 1e3 * seconds_per_call(twin_graphed, 500),
                "gpu_twin_q_update_eager_ms": lambda: 1e3 * seconds_per_call(twin_eager, 500),
                "gpu_v_sac_update_graphed_ms": lambda: 1e3 * seconds_per_call(v_graphed, 500),
            },
        )
    )
    print(f"measuring runs of {steps} steps on the GPU and on one CPU core ...", flush=True)
    near = {"guide_threshold": 0.1}
    results.update(
        median_of(
            repeats,
            {
                "gpu_harness_twin_q_steps_per_s": lambda: harness_run_steps_per_s(
                    "sac-twin-q", steps, device="cuda"
                ),
                "gpu_harness_twin_q_eager_steps_per_s": lambda: harness_run_steps_per_s(
                    "sac-twin-q", steps, device="cuda", cuda_graphs=False
                ),
                "gpu_harness_v_sac_steps_per_s": lambda: harness_run_steps_per_s(
                    "sac", steps, device="cuda"
                ),
                "gpu_drl_eg_1k_steps_per_s": lambda: harness_run_steps_per_s(
                    "drl-eg", steps, near, hopper_demos(1000), device="cuda"
                ),
                "gpu_sb3_sac_steps_per_s": lambda: sb3_sac_steps_per_s(steps, "cuda"),
                "cpu_harness_twin_q_steps_per_s": lambda: harness_run_steps_per_s(
                    "sac-twin-q", steps
                ),
                "cpu_sb3_sac_steps_per_s": lambda: sb3_sac_steps_per_s(steps),
            },
        )
    )
    runs = 2 * cores  # two rounds: workers that finish early take more runs
    print(
        f"measuring the machine: {runs} seeds on {cores} processes; SB3 and the harness on "
        "the CPU cores, and the harness with some of its processes on the GPU ...",
        flush=True,
    )
    results["gpu_machine_sb3_cpu_steps_per_s"] = machine_steps_per_s("sb3", steps, cores, runs)
    results["gpu_machine_harness_cpu_steps_per_s"] = machine_steps_per_s(
        "sac-twin-q", steps, cores, runs
    )
    for on_gpu in GPU_WORKER_COUNTS:
        label = on_gpu or cores
        results[f"gpu_machine_harness_{label}_on_gpu_steps_per_s"] = machine_steps_per_s(
            "sac-twin-q", steps, cores, runs, worker_devices("auto", cores, on_gpu)
        )
        print(
            f"  {label} on the GPU: "
            f"{results[f'gpu_machine_harness_{label}_on_gpu_steps_per_s']:.0f} steps/s",
            flush=True,
        )
    split = sac_time_split("sac-twin-q", steps, "cuda")
    print("\nwhere a twin-Q SAC run on the GPU spends its time (share of wall time):")
    for name, share in split.items():
        print(f"  {name:48} {100 * share:5.1f}%")
        results[f"gpu_twin_q_run_share {name}"] = share
    r = results
    rows = [
        (
            "GPU: one twin-Q SAC run / one SB3 SAC run, both on the GPU",
            r["gpu_harness_twin_q_steps_per_s"] / r["gpu_sb3_sac_steps_per_s"],
            ">= 1.5",
        ),
        (
            "GPU: one twin-Q SAC run on the GPU / one SB3 SAC run on a core",
            r["gpu_harness_twin_q_steps_per_s"] / r["cpu_sb3_sac_steps_per_s"],
            ">= 1.5",
        ),
        (
            "GPU: twin-Q run, graphed / eager",
            r["gpu_harness_twin_q_steps_per_s"] / r["gpu_harness_twin_q_eager_steps_per_s"],
            "(what CUDA graphs buy)",
        ),
        (
            "GPU: twin-Q update, eager / graphed",
            r["gpu_twin_q_update_eager_ms"] / r["gpu_twin_q_update_graphed_ms"],
            "(launch overhead removed)",
        ),
        (
            "GPU: twin-Q run on the GPU / on one core",
            r["gpu_harness_twin_q_steps_per_s"] / r["cpu_harness_twin_q_steps_per_s"],
            "",
        ),
        (
            "GPU: paper V-SAC run / SB3 SAC run, both on the GPU",
            r["gpu_harness_v_sac_steps_per_s"] / r["gpu_sb3_sac_steps_per_s"],
            "",
        ),
        (
            "GPU: DRL-EG step time / V-SAC step time (1000 demos, T2 = 0.1)",
            r["gpu_harness_v_sac_steps_per_s"] / r["gpu_drl_eg_1k_steps_per_s"],
            "(whole runs; different trajectories)",
        ),
        (
            f"GPU machine, {runs} seeds: harness on {cores} cores / SB3 on {cores} cores",
            r["gpu_machine_harness_cpu_steps_per_s"] / r["gpu_machine_sb3_cpu_steps_per_s"],
            "",
        ),
    ]
    for on_gpu in GPU_WORKER_COUNTS:
        label = on_gpu or cores
        mode = "the default, all" if on_gpu is None else f"--gpu-workers {on_gpu}"
        rows.append(
            (
                f"GPU machine, {runs} seeds: harness, {label} of {cores} processes on the "
                f"GPU ({mode}) / SB3 on {cores} cores",
                r[f"gpu_machine_harness_{label}_on_gpu_steps_per_s"]
                / r["gpu_machine_sb3_cpu_steps_per_s"],
                ">= 1.5",
            )
        )
    return results, rows


def print_table(rows: list[tuple]) -> None:
    print(f"\n{'ratio':66} {'measured':>9}  target")
    for name, value, target in rows:
        print(f"{name:66} {value:9.3f}  {target}")


def report(
    out: Path,
    command: str,
    steps: int,
    repeats: int,
    results: dict[str, float],
    rows: list[tuple],
    **extra,
) -> None:
    """Print the ratios and the raw measurements, and write them, with the machine, to ``out``."""
    print_table(rows)
    print("\nraw measurements:")
    for name, value in results.items():
        print(f"  {name:52} {value:12.3f}")
    machine = {
        "platform": platform.platform(),
        "cpus": os.cpu_count() or 1,
        "torch": torch.__version__,
    }
    if torch.cuda.is_available():
        machine["gpu"] = torch.cuda.get_device_name()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {
                "machine": machine,
                "command": command,
                "hopper_steps_per_run": steps,
                "repeats": repeats,
                "measurements": results,
                "ratios": [{"name": n, "value": v, "target": t} for n, v, t in rows],
                **extra,
            },
            indent=2,
        )
        + "\n"
    )


def main_gpu(args: argparse.Namespace) -> None:
    """``--gpu-only``: the GPU section alone, into its own file."""
    began = time.perf_counter()
    results, rows = gpu_measurements(args.steps, args.repeats)
    results["bench_wall_s"] = time.perf_counter() - began
    out = args.out.with_name("bench_gpu.json")
    report(
        out,
        " ".join(["benchmarks/bench.py", *sys.argv[1:]]),
        args.steps,
        args.repeats,
        results,
        rows,
    )
    print(f"\nwritten: {out} ({results['bench_wall_s']:.0f} s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--steps",
        type=int,
        default=2500,
        help="env steps per SAC run (the first 1000 without updates)",
    )
    parser.add_argument(
        "--repeats", type=int, default=3, help="whole-run measurements are the median of this many"
    )
    parser.add_argument("--out", type=Path, default=Path("reports/bench/bench.json"))
    parser.add_argument(
        "--gpu-only",
        action="store_true",
        help="measure only the GPU path (reports/bench/bench_gpu.json)",
    )
    args = parser.parse_args()
    if args.steps <= WARMUP or args.repeats < 1:
        parser.error(f"--steps must exceed {WARMUP} (the warm-up) and --repeats be >= 1")
    torch.set_num_threads(1)
    if args.gpu_only:
        if not torch.cuda.is_available():
            parser.error("--gpu-only needs a CUDA GPU, and torch sees none")
        main_gpu(args)
        return
    steps, repeats = args.steps, args.repeats
    update_steps = steps - WARMUP
    results: dict[str, float] = {}
    began = time.perf_counter()

    print("measuring env adapters ...", flush=True)
    results.update(bench_env(20_000))
    print("measuring the update floor and the harness's updates ...", flush=True)
    floor_update = make_floor_update()
    v_update, twin_update = make_harness_update("sac"), make_harness_update("sac-twin-q")
    results.update(
        median_of(
            repeats,
            {
                "floor_twin_q_update_ms": lambda: 1e3 * seconds_per_call(floor_update, 300),
                "harness_twin_q_update_ms": lambda: 1e3 * seconds_per_call(twin_update, 300),
                "harness_v_sac_update_ms": lambda: 1e3 * seconds_per_call(v_update, 300),
            },
        )
    )
    print("measuring the CPU's matrix-product rate and the updates' FLOPs ...", flush=True)
    results["gemm_256_gflops"] = gemm_gflops()
    for name, update in (
        ("floor", floor_update),
        ("harness_twin_q", twin_update),
        ("harness_v_sac", v_update),
    ):
        results[f"{name}_update_mflop"] = flops_per_call(update) / 1e6
        # the time the update's products alone would take at the best rate measured above
        results[f"{name}_update_flop_ms"] = (
            results[f"{name}_update_mflop"] / results["gemm_256_gflops"]
        )
    profile_rows = update_profile(twin_update)
    print(
        f"measuring SAC runs (harness twin-Q, harness V-SAC, SB3; median of {repeats}) ...",
        flush=True,
    )
    results.update(
        median_of(
            repeats,
            {
                "harness_twin_q_sac_steps_per_s": lambda: harness_run_steps_per_s(
                    "sac-twin-q", steps
                ),
                "harness_v_sac_steps_per_s": lambda: harness_run_steps_per_s("sac", steps),
                "sb3_sac_steps_per_s": lambda: sb3_sac_steps_per_s(steps),
            },
        )
    )
    print("measuring DRL-EG guidance (1000 and 1M demonstrations) ...", flush=True)
    # T2 = 0.1: a realistic threshold (Hopper's demonstration spacing is ~0.1); always:
    # the guider answers every step, the index's worst case
    for label, pairs in (("1k", 1000), ("1m", 1_000_000)):
        for mode, threshold in (("near", 0.1), ("always", 1e6)):
            for key, value in guidance_cost(pairs, threshold).items():
                results[f"guidance_{label}_{mode}_{key}"] = value
    near = {"guide_threshold": 0.1}
    results.update(
        median_of(
            repeats,
            {
                "drl_eg_1k_steps_per_s": lambda: harness_run_steps_per_s(
                    "drl-eg", steps, near, hopper_demos(1000)
                ),
                "drl_eg_sac_steps_per_s": lambda: harness_run_steps_per_s("sac", steps),
            },
        )
    )
    print("measuring PPO (harness, SB3) ...", flush=True)
    results.update(
        median_of(
            repeats,
            {
                "harness_ppo_steps_per_s": lambda: harness_run_steps_per_s("ppo", 4 * 2048),
                "sb3_ppo_steps_per_s": lambda: sb3_ppo_steps_per_s(4 * 2048),
            },
        )
    )
    ppo_split = ppo_time_split()
    sac_split = sac_time_split("sac-twin-q", steps)
    cores = os.cpu_count() or 1
    seeds = max(4, cores)
    print(f"measuring the machine: {seeds} seeds on {cores} processes ...", flush=True)
    results.update(
        median_of(
            max(1, repeats - 1),
            {
                "machine_harness_sac_steps_per_s": lambda: machine_steps_per_s(
                    "sac-twin-q", steps, cores, seeds
                ),
                "machine_sb3_sac_steps_per_s": lambda: machine_steps_per_s(
                    "sb3", steps, cores, seeds
                ),
            },
        )
    )

    # the floor of a whole run: its updates at the floor's cost plus its raw env steps
    floor_run_s = (
        update_steps * results["floor_twin_q_update_ms"] / 1e3
        + steps / results["raw_env_steps_per_s"]
    )
    twin_run_s = steps / results["harness_twin_q_sac_steps_per_s"]
    results["floor_sac_run_steps_per_s"] = steps / floor_run_s
    # SB3's update cost, from its run time less the raw env time
    sb3_update_s = (
        steps / results["sb3_sac_steps_per_s"] - steps / results["raw_env_steps_per_s"]
    ) / update_steps
    results["sb3_sac_update_ms_estimated"] = 1e3 * sb3_update_s
    # guidance against the time of a whole SAC env step (its update included)
    sac_step_us = 1e6 / results["harness_v_sac_steps_per_s"]
    paper_run_steps = 1_000_000

    def guidance_ratio(label: str, mode: str) -> float:
        added = results[f"guidance_{label}_{mode}_added_us_per_step"]
        build_us = 1e6 * results[f"guidance_{label}_{mode}_index_build_s"] / paper_run_steps
        return (sac_step_us + added + build_us) / sac_step_us

    rows = [
        (
            "one twin-Q SAC run / one SB3 SAC run",
            results["harness_twin_q_sac_steps_per_s"] / results["sb3_sac_steps_per_s"],
            ">= 1.5",
        ),
        (
            "one paper V-SAC run / one SB3 SAC run",
            results["harness_v_sac_steps_per_s"] / results["sb3_sac_steps_per_s"],
            "(five networks against SB3's four)",
        ),
        (
            f"machine, {seeds}-seed job on {cores} processes: harness / SB3",
            results["machine_harness_sac_steps_per_s"] / results["machine_sb3_sac_steps_per_s"],
            ">= 1.5",
        ),
        (
            "twin-Q SAC run time / floor (updates + raw env steps)",
            twin_run_s / floor_run_s,
            "<= 1.3",
        ),
        (
            "twin-Q SAC update / floor update",
            results["harness_twin_q_update_ms"] / results["floor_twin_q_update_ms"],
            "(same math)",
        ),
        (
            "twin-Q SAC update / its FLOPs at the measured GEMM rate",
            results["harness_twin_q_update_ms"] / results["harness_twin_q_update_flop_ms"],
            "(>= 1 by law)",
        ),
        (
            "SB3 SAC update / its FLOPs at the measured GEMM rate",
            results["sb3_sac_update_ms_estimated"] / results["floor_update_flop_ms"],
            "(SB3's distance from the hardware)",
        ),
        (
            "PPO / SB3 PPO",
            results["harness_ppo_steps_per_s"] / results["sb3_ppo_steps_per_s"],
            ">= 1.5",
        ),
        ("DRL-EG step / SAC step, 1000 demos, T2 = 0.1", guidance_ratio("1k", "near"), "<= 1.05"),
        ("DRL-EG step / SAC step, 1M demos, T2 = 0.1", guidance_ratio("1m", "near"), "<= 1.05"),
        (
            "DRL-EG step / SAC step, 1000 demos, guided always",
            guidance_ratio("1k", "always"),
            "(D(s) and G(s) on every step; the policy still runs)",
        ),
        (
            "DRL-EG step / SAC step, 1M demos, guided always",
            guidance_ratio("1m", "always"),
            "(the index's worst case)",
        ),
        (
            "whole DRL-EG run time / SAC run, 1000 demos, T2 = 0.1",
            results["drl_eg_sac_steps_per_s"] / results["drl_eg_1k_steps_per_s"],
            "(different trajectories; noisy)",
        ),
        (
            "adapter time per step / raw env",
            results["raw_env_steps_per_s"] / results["adapter_env_steps_per_s"],
            "<= 1.05",
        ),
    ]
    if torch.cuda.is_available():  # the GPU path, when there is one, beside the CPU's
        gpu_results, gpu_rows = gpu_measurements(steps, repeats)
        results.update(gpu_results)
        rows += gpu_rows
    results["bench_wall_s"] = time.perf_counter() - began
    report(
        args.out,
        "nox -s bench",
        steps,
        repeats,
        results,
        rows,
        twin_q_update_profile=profile_rows,
        twin_q_run_time_split=sac_split,
        ppo_time_split=ppo_split,
    )
    print("\nwhere the harness's twin-Q SAC update spends its time (self CPU time):")
    for row in profile_rows:
        print(f"  {row['op']:40} {100 * row['share']:5.1f}%  {row['calls_per_update']:5.1f} calls")
    print("\nwhere the harness's twin-Q SAC run spends its time (share of wall time):")
    for name, share in sac_split.items():
        print(f"  {name:48} {100 * share:5.1f}%")
    print("\nwhere the harness's PPO run spends its time (share of wall time):")
    for name, share in ppo_split.items():
        print(f"  {name:40} {100 * share:5.1f}%")
    print(f"\nwritten: {args.out} ({results['bench_wall_s']:.0f} s)")


if __name__ == "__main__":
    main()
