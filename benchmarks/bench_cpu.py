"""The CPU section of ``nox -s bench``: the harness against Stable-Baselines3 and against
the hardware floor, each target a ratio of two numbers measured here."""

from __future__ import annotations

import os
from typing import Any

from bench_measure import (
    WARMUP,
    bench_env,
    flops_per_call,
    gemm_gflops,
    guidance_cost,
    harness_run_steps_per_s,
    hopper_demos,
    machine_steps_per_s,
    make_floor_update,
    make_harness_update,
    median_of,
    sb3_ppo_steps_per_s,
    sb3_sac_steps_per_s,
    seconds_per_call,
)
from bench_time_split import ppo_time_split, sac_time_split, update_profile


def cpu_measurements(
    steps: int, repeats: int
) -> tuple[dict[str, float], list[tuple], dict[str, Any]]:
    """The measurements, the ratio rows (name, value, target) and where the time goes (the
    twin-Q update's operators, a twin-Q run's and a PPO run's shares)."""
    update_steps = steps - WARMUP
    results: dict[str, float] = {}

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
    where_time_goes = {
        "twin_q_update_profile": profile_rows,
        "twin_q_run_time_split": sac_split,
        "ppo_time_split": ppo_split,
    }
    return results, rows, where_time_goes
