"""Where the time goes: an update's operators (torch's profiler), and the shares of a PPO
run's and a SAC run's wall time spent in the env, the policy, the replay and the gradient
steps."""

from __future__ import annotations

import time
from collections.abc import Callable

import torch

from bench_measure import ENV_ID


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
