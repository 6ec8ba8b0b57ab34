"""Throughput benchmark: the harness against Stable-Baselines3 and against the hardware floor.

Every number is measured in this one run on this machine, and every target is a ratio of two
such numbers, so the table means the same on a laptop and on a server. Run it with
``nox -s bench`` (which installs stable-baselines3, a bench-only dependency); it prints the
table and writes ``reports/bench/bench.json``.

Measurements (Hopper-v5, one torch thread per process, batch 256, 2x256 networks, one
gradient step per env step after 1000 steps from the initial policy):

- env: raw Gymnasium env against the harness's adapter, random actions;
- floor: a bare twin-Q, auto-alpha SAC update in plain PyTorch, the least any SAC can cost;
- the harness's SAC (the paper's V-network version): its update alone and its training loop;
- Stable-Baselines3 SAC with the same hyperparameters;
- DRL-EG with guidance consulted on every step, with 1000 and with 1,000,000 demonstrations;
- the harness's PPO against SB3's PPO (2048-step rollouts, 10 epochs, minibatch 64, 2x64);
- the machine: one training process per core at once, harness and SB3.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

ENV_ID = "Hopper-v5"
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
    for _ in range(3):  # interleaved, best of three: warm-up and noise hit both alike
        raw.append(env_steps_per_s(lambda: gym.make(ENV_ID), steps))
        adapter.append(env_steps_per_s(lambda: make_env(ENV_ID), steps))
    return {"raw_env_steps_per_s": max(raw), "adapter_env_steps_per_s": max(adapter)}


def make_floor_update(obs_dim: int = 11, act_dim: int = 3) -> Callable[[], None]:
    """One update of a minimal twin-Q, auto-alpha SAC: nothing but the math."""
    from torch import nn

    torch.manual_seed(0)

    def net(inputs: int, outputs: int) -> nn.Module:
        return nn.Sequential(nn.Linear(inputs, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(),
                             nn.Linear(256, outputs))

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
        logp = (-0.5 * ((u - mean) / std) ** 2 - std.log()).sum(-1, keepdim=True) \
            - torch.log(1 - a.pow(2) + 1e-6).sum(-1, keepdim=True)
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
            for t, s in zip([*q1_t.parameters(), *q2_t.parameters()],
                            [*q1.parameters(), *q2.parameters()], strict=True):
                t.lerp_(s, 0.005)

    return update


def make_harness_update() -> Callable[[], None]:
    """One update of the harness's SAC (the paper's V-network version) on a filled buffer."""
    from baselines.common.buffer import ReplayBuffer
    from baselines.sac import SACAgent, SACConfig

    agent = SACAgent(11, 3, -np.ones(3), np.ones(3), SACConfig(), seed=0)
    buffer, rng = ReplayBuffer(11, 3, 10_000), np.random.default_rng(0)
    for _ in range(5000):
        buffer.add(rng.normal(size=11), rng.uniform(-1, 1, 3), 1.0, rng.normal(size=11), False)
    return lambda: agent.update(buffer.sample(256, rng))


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
    return 2 * size ** 3 / seconds / 1e9


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
    return [{"op": e.key, "share": round(e.self_cpu_time_total / total, 3),
             "calls_per_update": round(e.count / calls, 1)} for e in events[:top]]


def harness_run_steps_per_s(algo: str, steps: int, overrides: dict | None = None,
                            demos=None) -> float:
    """Env steps per second of a whole training run (updates from step 1000 on)."""
    from baselines.common.context import TrainContext
    from baselines.registry import get_algorithm

    algorithm = get_algorithm(algo)
    config = algorithm.make_config(overrides or {})
    ctx = TrainContext(env_id=ENV_ID, seed=0, total_steps=steps, eval_interval=10 * steps,
                       eval_episodes=1, demos=demos)
    start = time.perf_counter()
    algorithm.train(ctx, config)
    return steps / (time.perf_counter() - start)


def synthetic_demos(n_pairs: int):
    """Hopper-shaped demonstrations near the start states (the speed, not the skill, counts)."""
    from replicate.demos import Demonstrations

    rng = np.random.default_rng(0)
    observations = (rng.normal(scale=0.05, size=(n_pairs, 11))
                    + np.r_[1.25, np.zeros(10)]).astype(np.float32)
    actions = rng.uniform(-1, 1, size=(n_pairs, 3)).astype(np.float32)
    return Demonstrations(observations, actions, {"expert_return_mean": 1e9})


def sb3_sac_steps_per_s(steps: int) -> float:
    import gymnasium as gym
    from stable_baselines3 import SAC

    torch.set_num_threads(1)
    model = SAC("MlpPolicy", gym.make(ENV_ID), learning_rate=3e-4, buffer_size=steps,
                learning_starts=WARMUP, batch_size=256, tau=0.005, gamma=0.99, train_freq=1,
                gradient_steps=1, policy_kwargs={"net_arch": [256, 256]}, seed=0,
                device="cpu", verbose=0)
    start = time.perf_counter()
    model.learn(total_timesteps=steps)
    return steps / (time.perf_counter() - start)


def sb3_ppo_steps_per_s(steps: int) -> float:
    import gymnasium as gym
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    model = PPO("MlpPolicy", gym.make(ENV_ID), n_steps=2048, batch_size=64, n_epochs=10,
                policy_kwargs={"net_arch": [64, 64]}, seed=0, device="cpu", verbose=0)
    start = time.perf_counter()
    model.learn(total_timesteps=steps)
    return steps / (time.perf_counter() - start)


def _one_process(job: tuple[str, int]) -> float:
    kind, steps = job
    torch.set_num_threads(1)
    if kind == "sb3":
        return sb3_sac_steps_per_s(steps)
    return harness_run_steps_per_s("sac", steps)


def machine_steps_per_s(kind: str, steps: int, processes: int) -> float:
    """Total env steps per second of ``processes`` SAC runs at once, one per core."""
    with mp.get_context("spawn").Pool(processes) as pool:
        start = time.perf_counter()
        pool.map(_one_process, [(kind, steps)] * processes)
        return processes * steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2500,
                        help="env steps per SAC run (the first 1000 without updates)")
    parser.add_argument("--out", type=Path, default=Path("reports/bench/bench.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    steps = args.steps
    update_steps = steps - WARMUP
    results: dict[str, float] = {}

    print("measuring env adapters ...", flush=True)
    results.update(bench_env(20_000))
    print("measuring the update floor and the harness's update ...", flush=True)
    floor_update, harness_update = make_floor_update(), make_harness_update()
    results["floor_twin_q_update_ms"] = 1e3 * seconds_per_call(floor_update, update_steps // 2)
    results["harness_v_sac_update_ms"] = 1e3 * seconds_per_call(harness_update,
                                                                update_steps // 2)
    print("measuring the CPU's matrix-product rate and the updates' FLOPs ...", flush=True)
    results["gemm_256_gflops"] = gemm_gflops()
    results["floor_update_mflop"] = flops_per_call(floor_update) / 1e6
    results["harness_update_mflop"] = flops_per_call(harness_update) / 1e6
    # the time an update's products alone would take at the best rate measured above
    results["floor_update_flop_ms"] = results["floor_update_mflop"] / results["gemm_256_gflops"]
    results["harness_update_flop_ms"] = (results["harness_update_mflop"]
                                         / results["gemm_256_gflops"])
    profile_rows = update_profile(harness_update)
    print("measuring SAC runs (harness, SB3) ...", flush=True)
    results["harness_sac_steps_per_s"] = harness_run_steps_per_s("sac", steps)
    results["sb3_sac_steps_per_s"] = sb3_sac_steps_per_s(steps)
    print("measuring DRL-EG guidance (1000 and 1M demonstrations) ...", flush=True)
    # T2 = 0.1: guided near the demonstrations, searched-and-pruned far from them, as in a
    # real run; T2 = always: the guider answers every step, the KD-tree's worst case
    near = {"guide_threshold": 0.1}
    always = {"guide_threshold": 1e6}
    thousand, million = synthetic_demos(1000), synthetic_demos(1_000_000)
    results["drl_eg_1k_steps_per_s"] = harness_run_steps_per_s("drl-eg", steps, near, thousand)
    results["drl_eg_1m_steps_per_s"] = harness_run_steps_per_s("drl-eg", steps, near, million)
    results["drl_eg_1k_always_steps_per_s"] = harness_run_steps_per_s(
        "drl-eg", steps, always, thousand)
    results["drl_eg_1m_always_steps_per_s"] = harness_run_steps_per_s(
        "drl-eg", steps, always, million)
    print("measuring PPO (harness, SB3) ...", flush=True)
    results["harness_ppo_steps_per_s"] = harness_run_steps_per_s("ppo", 4 * 2048)
    results["sb3_ppo_steps_per_s"] = sb3_ppo_steps_per_s(4 * 2048)
    cores = os.cpu_count() or 1
    print(f"measuring the machine: {cores} SAC runs at once ...", flush=True)
    results["machine_harness_sac_steps_per_s"] = machine_steps_per_s("harness", steps, cores)
    results["machine_sb3_sac_steps_per_s"] = machine_steps_per_s("sb3", steps, cores)

    # the floor of a whole run: its updates at the floor's cost plus its raw env steps
    floor_run_s = (update_steps * results["floor_twin_q_update_ms"] / 1e3
                   + steps / results["raw_env_steps_per_s"])
    sac_run_s = steps / results["harness_sac_steps_per_s"]
    results["floor_sac_run_steps_per_s"] = steps / floor_run_s
    # SB3's update cost, from its run time less the raw env time
    sb3_update_s = (steps / results["sb3_sac_steps_per_s"]
                    - steps / results["raw_env_steps_per_s"]) / update_steps
    results["sb3_sac_update_ms_estimated"] = 1e3 * sb3_update_s
    rows = [
        ("one SAC run / one SB3 SAC run", results["harness_sac_steps_per_s"]
         / results["sb3_sac_steps_per_s"], ">= 1.5"),
        (f"machine, {cores} SAC runs / {cores} SB3 runs", results["machine_harness_sac_steps_per_s"]
         / results["machine_sb3_sac_steps_per_s"], ">= 1.5"),
        ("SAC run time / twin-Q floor (updates + raw env steps)", sac_run_s / floor_run_s,
         "<= 1.3"),
        ("harness V-SAC update / twin-Q floor update", results["harness_v_sac_update_ms"]
         / results["floor_twin_q_update_ms"], "(the paper's SAC has a fifth network)"),
        ("SB3 SAC update / its FLOPs at the measured GEMM rate",
         results["sb3_sac_update_ms_estimated"] / results["floor_update_flop_ms"],
         "(how far any SAC of this size can beat SB3 on this CPU)"),
        ("harness V-SAC update / its FLOPs at the measured GEMM rate",
         results["harness_v_sac_update_ms"] / results["harness_update_flop_ms"], "(>= 1 by law)"),
        ("PPO / SB3 PPO", results["harness_ppo_steps_per_s"] / results["sb3_ppo_steps_per_s"],
         ">= 1.5"),
        ("DRL-EG 1k demos, T2 = 0.1, time / SAC", results["harness_sac_steps_per_s"]
         / results["drl_eg_1k_steps_per_s"], "<= 1.05"),
        ("DRL-EG 1M demos, T2 = 0.1, time / SAC", results["harness_sac_steps_per_s"]
         / results["drl_eg_1m_steps_per_s"], "<= 1.05"),
        ("DRL-EG 1k demos, guided always, time / SAC", results["harness_sac_steps_per_s"]
         / results["drl_eg_1k_always_steps_per_s"], "<= 1.05"),
        ("DRL-EG 1M demos, guided always, time / SAC", results["harness_sac_steps_per_s"]
         / results["drl_eg_1m_always_steps_per_s"], "<= 1.05"),
        ("adapter time per step / raw env", results["raw_env_steps_per_s"]
         / results["adapter_env_steps_per_s"], "<= 1.05"),
    ]
    print(f"\n{'ratio':52} {'measured':>9}  target")
    for name, value, target in rows:
        print(f"{name:52} {value:9.3f}  {target}")
    print("\nraw measurements:")
    for name, value in results.items():
        print(f"  {name:40} {value:12.2f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "machine": {"platform": platform.platform(), "cpus": cores,
                    "torch": torch.__version__},
        "hopper_steps_per_run": steps, "measurements": results,
        "ratios": [{"name": n, "value": v, "target": t} for n, v, t in rows],
        "harness_update_profile": profile_rows}, indent=2) + "\n")
    print("\nwhere the harness's SAC update spends its time (self CPU time):")
    for row in profile_rows:
        print(f"  {row['op']:40} {100 * row['share']:5.1f}%  {row['calls_per_update']:5.1f} calls")
    print(f"\nwritten: {args.out}")


if __name__ == "__main__":
    main()
