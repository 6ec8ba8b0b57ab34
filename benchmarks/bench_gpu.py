"""The GPU section of ``nox -s bench`` (where torch sees a CUDA GPU, or alone with
``benchmarks/bench.py --gpu-only``): graphed against eager updates, whole runs against SB3 on
the same GPU and on one core, and a job of two seeds per core with some processes on the
GPU."""

from __future__ import annotations

import os

import torch

from baselines.common.device import worker_devices

from bench_measure import (
    harness_run_steps_per_s,
    hopper_demos,
    machine_steps_per_s,
    make_harness_update,
    median_of,
    sb3_sac_steps_per_s,
    seconds_per_call,
)
from bench_time_split import sac_time_split

GPU_WORKER_COUNTS = (1, 2, 4, None)  # processes on the GPU in the machine job (None: all)


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
