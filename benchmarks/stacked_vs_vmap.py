"""The trainer's stacked networks against ``torch.vmap`` over ordinary modules, on CPU.

One gradient step of the paper's V-SAC (Q, V and policy losses and their Adam steps, the
Polyak step of V'; ``baselines.sac``) for a seed batch of N = 1, 2, 4, 8 members, Hopper-v5
sizes (obs 11, act 3), 2x256 networks, batch 256 per member, one torch thread, two ways:

- stacked: the trainer itself, ``SACAgent(seeds, ...).update(rngs)`` on a filled replay
  (every layer one ``baddbmm`` over the members, ``baselines.common.stacked``);
- vmap: the same members' initial networks as ordinary ``torch.nn`` MLPs, ensembled with
  ``torch.func.stack_module_state`` and called through ``functional_call`` under
  ``torch.vmap``, the same V-SAC loss written on them, and ``torch.optim.Adam`` (fused, as
  the trainer's is on CPU) over the stacked parameters. Both critics of a member are
  vmapped together (2N critics), as the trainer pairs them.

Both timed calls draw the minibatch from the same replay and the noise from per-member
generators, so they differ only in the step. Before timing, one step of each on the same
minibatch and noise, from the same initial weights, must give the same losses (the two
compute the same function). Stacked and vmap calls are interleaved in rounds, and each
time is the median over the rounds; the ratio vmap / stacked is what to read (above 1:
vmap is slower).

    python benchmarks/stacked_vs_vmap.py [--rounds 3] [--calls 48] [--out PATH]

Writes ``reports/bench/stacked_vs_vmap.json``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.func import functional_call, stack_module_state

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from baselines.common.buffer import Batch  # noqa: E402
from baselines.common.device import flush_denormals  # noqa: E402
from baselines.common.networks import LOG_STD_MAX, LOG_STD_MIN, squashed_sample  # noqa: E402
from baselines.offpolicy import action_space  # noqa: E402
from baselines.sac import SACAgent, SACConfig, SACNetworks  # noqa: E402

ENV_ID, OBS, ACT = "Hopper-v5", 11, 3
MEMBERS = (1, 2, 4, 8)
REPLAY = 5000  # transitions per member in the replay the minibatches come from


def ensemble(models: list[nn.Module]) -> tuple[dict[str, torch.Tensor], Callable]:
    """The models' parameters stacked (members first, leaves that take gradients) and the
    vmapped function ``(params, x (members, B, in)) -> (members, B, out)``."""
    params, _ = stack_module_state(models)
    base = copy.deepcopy(models[0]).to("meta")

    def call(p: dict[str, torch.Tensor], x: torch.Tensor) -> torch.Tensor:
        return functional_call(base, (p,), (x,))

    return params, torch.vmap(call)


class VmapVSAC:
    """V-SAC's gradient step for N members on vmapped ordinary modules: the math of
    ``SACAgent.gradient_step``, from the same seeds' initial networks."""

    def __init__(self, seeds: list[int], config: SACConfig):
        _, _, low, high = action_space(ENV_ID)
        nets = [SACNetworks.initial(s, OBS, ACT, low, high, config) for s in seeds]
        self.config, self.members = config, len(seeds)
        # member-major pairs, as the trainer's critics: (m0 Q1, m0 Q2, m1 Q1, ...)
        self.q, self.q_fn = ensemble([m for n in nets for m in (n.q1.net, n.q2.net)])
        self.v, self.v_fn = ensemble([n.v.net for n in nets])
        self.v_target = {k: t.detach().clone() for k, t in self.v.items()}
        self.pi, self.pi_fn = ensemble([n.policy.trunk for n in nets])
        self.scale, self.bias = nets[0].policy.action_scale, nets[0].policy.action_bias
        lr = config.learning_rate
        self.q_opt = torch.optim.Adam(list(self.q.values()), lr=lr, fused=True)
        self.v_opt = torch.optim.Adam(list(self.v.values()), lr=lr, fused=True)
        self.pi_opt = torch.optim.Adam(list(self.pi.values()), lr=lr, fused=True)

    def critics(self, params: dict, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        """Both critics of every member: (N, B, .) inputs to (N, 2, B)."""
        n, rows = obs.shape[0], obs.shape[1]
        x = torch.cat([obs, act], -1).unsqueeze(1).expand(-1, 2, -1, -1).reshape(2 * n, rows, -1)
        return self.q_fn(params, x).view(n, 2, rows)

    def step(self, batch: Batch, noise: torch.Tensor) -> dict[str, torch.Tensor]:
        cfg = self.config
        obs, actions = batch.observations, batch.actions
        with torch.no_grad():
            next_v = self.v_fn(self.v_target, batch.next_observations).squeeze(-1)
            y_q = cfg.reward_scale * batch.rewards + cfg.gamma * (1.0 - batch.terminated) * next_v
        q_losses = 0.5 * (self.critics(self.q, obs, actions) - y_q[:, None]).pow(2).mean(-1).sum(-1)
        self.q_opt.zero_grad()
        q_losses.sum().backward()
        self.q_opt.step()

        mean, log_std = self.pi_fn(self.pi, obs).chunk(2, dim=-1)
        log_std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)
        new_actions, log_prob = squashed_sample(mean, log_std, noise, self.scale, self.bias)
        frozen = {k: t.detach() for k, t in self.q.items()}  # no critic weight gradients
        q_new = self.critics(frozen, obs, new_actions).min(dim=1).values
        v = self.v_fn(self.v, obs).squeeze(-1)
        v_losses = 0.5 * (v - (q_new - log_prob).detach()).pow(2).mean(-1)
        policy_losses = (log_prob - q_new).mean(-1)
        self.v_opt.zero_grad()
        v_losses.sum().backward()
        self.v_opt.step()
        self.pi_opt.zero_grad()
        policy_losses.sum().backward()
        self.pi_opt.step()
        with torch.no_grad():
            torch._foreach_lerp_(list(self.v_target.values()), list(self.v.values()), cfg.tau)
        return {
            "q_loss": q_losses.detach(),
            "v_loss": v_losses.detach(),
            "policy_loss": policy_losses.detach(),
        }


def filled_agent(seeds: list[int], config: SACConfig) -> SACAgent:
    """The trainer's agent for ``seeds`` with a replay of random transitions."""
    agent = SACAgent(seeds, ENV_ID, config)
    n = agent.members
    agent.buffer = agent.make_replay(n, OBS, REPLAY)
    rng = np.random.default_rng(3)
    for _ in range(REPLAY):
        agent.buffer.add(
            rng.normal(size=(n, OBS)).astype(np.float32),
            rng.uniform(-1, 1, size=(n, ACT)).astype(np.float32),
            rng.normal(size=n).astype(np.float32),
            rng.normal(size=(n, OBS)).astype(np.float32),
            (rng.random(n) < 0.1).astype(np.float32),
        )
    return agent


def member_noise(generators: list[torch.Generator], rows: int) -> torch.Tensor:
    """Each member's standard normal noise from its own generator (as the trainer draws it)."""
    return torch.stack([torch.randn((rows, ACT), generator=g) for g in generators])


def losses_agree(config: SACConfig, members: int = 2) -> float:
    """Largest relative difference of the first step's losses, stacked against vmap, from the
    same initial weights on the same minibatch and noise."""
    seeds = list(range(members))
    agent, vmapped = filled_agent(seeds, config), VmapVSAC(seeds, config)
    batch = agent.buffer.sample(config.batch_size, [np.random.default_rng(s) for s in seeds])
    noise = member_noise([torch.Generator().manual_seed(s + 1) for s in seeds], config.batch_size)
    a, b = agent.gradient_step(batch, noise), vmapped.step(batch, noise)
    return max(float(((a[k] - b[k]).abs() / a[k].abs().clamp(min=1e-6)).max()) for k in b)


def per_call_ms(fn: Callable[[], object], calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        fn()
    return 1e3 * (time.perf_counter() - start) / calls


def measure(members: int, config: SACConfig, rounds: int, calls: int) -> dict:
    seeds = list(range(members))
    agent = filled_agent(seeds, config)
    vmapped = VmapVSAC(seeds, config)
    stacked_rngs = [np.random.default_rng(s) for s in seeds]
    vmap_rngs = [np.random.default_rng(s) for s in seeds]
    generators = [torch.Generator().manual_seed(s + 1) for s in seeds]

    def stacked_update() -> object:
        return agent.update(stacked_rngs)

    def vmap_update() -> object:
        batch = agent.buffer.sample(config.batch_size, vmap_rngs)
        return vmapped.step(batch, member_noise(generators, config.batch_size))

    for _ in range(3):  # warm-up: first calls, allocations, vmap's first trace
        stacked_update()
        vmap_update()
    times: dict[str, list[float]] = {"stacked": [], "vmap": []}
    for _ in range(rounds):  # interleaved, so a slow spell hits both
        times["stacked"].append(per_call_ms(stacked_update, calls))
        times["vmap"].append(per_call_ms(vmap_update, calls))
    stacked, vmap = (float(np.median(times[k])) for k in ("stacked", "vmap"))
    return {
        "members": members,
        "calls per round": calls,
        "stacked ms": round(stacked, 3),
        "vmap ms": round(vmap, 3),
        "stacked ms per member": round(stacked / members, 3),
        "vmap ms per member": round(vmap / members, 3),
        "vmap / stacked": round(vmap / stacked, 3),
        "rounds ms": {k: [round(t, 3) for t in v] for k, v in times.items()},
    }


def cpu_model() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                return line.split(":", 1)[1].strip()
    except (OSError, subprocess.CalledProcessError):
        pass
    return platform.processor() or "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds; median")
    parser.add_argument(
        "--calls", type=int, default=48, help="calls per round at N = 1 (N members: calls / N)"
    )
    parser.add_argument("--out", type=Path, default=Path("reports/bench/stacked_vs_vmap.json"))
    args = parser.parse_args()
    if args.rounds < 1 or args.calls < 1:
        parser.error("--rounds and --calls must be >= 1")
    torch.set_num_threads(1)
    config = SACConfig()
    began = time.perf_counter()
    results = []
    with flush_denormals():  # as the trainer runs (baselines/registry.py)
        agreement = losses_agree(config)
        print(f"first-step losses, vmap against stacked: max relative difference {agreement:.2e}")
        if agreement > 1e-4:
            raise SystemExit("the two steps do not compute the same losses")
        print(f"{'N':>3} {'stacked ms':>11} {'vmap ms':>9} {'vmap/stacked':>13}", flush=True)
        for members in MEMBERS:
            row = measure(members, config, args.rounds, max(3, args.calls // members))
            results.append(row)
            print(
                f"{members:3d} {row['stacked ms']:11.2f} {row['vmap ms']:9.2f} "
                f"{row['vmap / stacked']:13.3f}",
                flush=True,
            )
    machine = {
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpus": os.cpu_count() or 1,
        "torch": torch.__version__,
        "torch threads": torch.get_num_threads(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "machine": machine,
                "command": " ".join(["benchmarks/stacked_vs_vmap.py", *sys.argv[1:]]),
                "setting": {
                    "algorithm": "sac (V-SAC) gradient step, replay sampling and noise included",
                    "env sizes": {"obs": OBS, "act": ACT, "env": ENV_ID},
                    "hidden": list(config.hidden_sizes),
                    "batch per member": config.batch_size,
                    "rounds": args.rounds,
                },
                "first step losses max relative difference": agreement,
                "results": results,
                "wall_s": round(time.perf_counter() - began, 1),
            },
            indent=1,
        )
        + "\n"
    )
    print(f"written: {args.out} ({time.perf_counter() - began:.0f} s)")


if __name__ == "__main__":
    main()
