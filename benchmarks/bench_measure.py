"""What ``nox -s bench`` measures, one function a measurement: env steps, gradient steps
of the harness and of a bare update, whole training runs of the harness and of
Stable-Baselines3, DRL-EG's guidance, and a seed job on every core. Hopper-v5 sizes, one
torch thread per process."""

from __future__ import annotations

import functools
import multiprocessing as mp
import time
from collections.abc import Callable

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
