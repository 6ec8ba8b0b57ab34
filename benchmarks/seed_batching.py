"""Would training several seeds in one process, with batched networks, pay on a CPU?

A stand-alone measurement behind a design decision (docs/performance.md): one twin-Q,
learned-temperature SAC update for K seeds at once, every layer of every network a batched
matrix product over the seeds (critics over 2K members), one torch thread, batch 256, 2x256
networks, Hopper's sizes. It prints the time of one K-seed update and its time per seed.

    python benchmarks/seed_batching.py
"""

from __future__ import annotations

import math
import time

import torch
from torch.nn import functional as F

OBS_DIM, ACT_DIM, BATCH, HIDDEN = 11, 3, 256, 256


def batched_mlp(members: int, sizes: list[int]) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Weights (members, in, out) and biases (members, 1, out) of ``members`` MLPs."""
    weights, biases = [], []
    for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
        weights.append(
            torch.nn.Parameter(torch.randn(members, fan_in, fan_out) / math.sqrt(fan_in))
        )
        biases.append(torch.nn.Parameter(torch.zeros(members, 1, fan_out)))
    return weights, biases


def forward(
    weights: list[torch.Tensor], biases: list[torch.Tensor], x: torch.Tensor
) -> torch.Tensor:
    for k, (weight, bias) in enumerate(zip(weights, biases)):
        x = torch.baddbmm(bias, x, weight)
        if k < len(weights) - 1:
            x = torch.relu(x)
    return x


def make_update(seeds: int):
    sizes_q = [OBS_DIM + ACT_DIM, HIDDEN, HIDDEN, 1]
    critic_w, critic_b = batched_mlp(2 * seeds, sizes_q)
    target_w, target_b = batched_mlp(2 * seeds, sizes_q)
    policy_w, policy_b = batched_mlp(seeds, [OBS_DIM, HIDDEN, HIDDEN, 2 * ACT_DIM])
    log_alpha = torch.zeros(seeds, 1, 1, requires_grad=True)
    critic_opt = torch.optim.Adam([*critic_w, *critic_b], fused=True)
    policy_opt = torch.optim.Adam([*policy_w, *policy_b], fused=True)
    alpha_opt = torch.optim.Adam([log_alpha], fused=True)
    obs, next_obs = torch.randn(seeds, BATCH, OBS_DIM), torch.randn(seeds, BATCH, OBS_DIM)
    actions = torch.rand(seeds, BATCH, ACT_DIM) * 2 - 1
    rewards, not_done = torch.randn(seeds, BATCH, 1), torch.ones(seeds, BATCH, 1)

    def sample(states: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, log_std = forward(policy_w, policy_b, states).chunk(2, -1)
        log_std = log_std.clamp(-20, 2)
        noise = torch.randn_like(mean)
        pre_tanh = mean + log_std.exp() * noise
        log_prob = (-0.5 * noise.pow(2) - log_std).sum(-1, keepdim=True) - (
            2 * (math.log(2) - pre_tanh - F.softplus(-2 * pre_tanh))
        ).sum(-1, keepdim=True)
        return torch.tanh(pre_tanh), log_prob

    def q_values(weights, biases, states, acts) -> torch.Tensor:
        pairs = torch.cat([states, acts], -1).unsqueeze(1).expand(-1, 2, -1, -1)
        return forward(weights, biases, pairs.reshape(2 * seeds, BATCH, -1)).view(
            seeds, 2, BATCH, 1
        )

    def update() -> None:
        alpha = log_alpha.detach().exp()
        with torch.no_grad():
            next_actions, next_log_prob = sample(next_obs)
            next_q = q_values(target_w, target_b, next_obs, next_actions).min(1).values
            y = rewards + 0.99 * not_done * (next_q - alpha * next_log_prob)
        q_loss = (
            0.5
            * (q_values(critic_w, critic_b, obs, actions) - y.unsqueeze(1))
            .pow(2)
            .mean((2, 3))
            .sum()
        )
        critic_opt.zero_grad()
        q_loss.backward()
        critic_opt.step()
        new_actions, log_prob = sample(obs)
        for p in [*critic_w, *critic_b]:
            p.requires_grad_(False)
        q_new = q_values(critic_w, critic_b, obs, new_actions).min(1).values
        for p in [*critic_w, *critic_b]:
            p.requires_grad_(True)
        policy_loss = (alpha * log_prob - q_new).mean((1, 2)).sum()
        policy_opt.zero_grad()
        policy_loss.backward()
        policy_opt.step()
        alpha_loss = -(log_alpha * (log_prob.detach() - ACT_DIM)).mean((1, 2)).sum()
        alpha_opt.zero_grad()
        alpha_loss.backward()
        alpha_opt.step()
        with torch.no_grad():
            torch._foreach_lerp_([*target_w, *target_b], [*critic_w, *critic_b], 0.005)

    return update


def main() -> None:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    print(f"{'seeds':>5} {'ms per update':>14} {'ms per seed':>12}")
    for seeds in (1, 2, 4, 8):
        update = make_update(seeds)
        for _ in range(20):
            update()
        calls = 200
        start = time.perf_counter()
        for _ in range(calls):
            update()
        ms = 1e3 * (time.perf_counter() - start) / calls
        print(f"{seeds:5d} {ms:14.2f} {ms / seeds:12.2f}", flush=True)


if __name__ == "__main__":
    main()
