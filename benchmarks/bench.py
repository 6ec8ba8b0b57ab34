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

The measurements are in ``bench_measure.py`` (and ``bench_time_split.py``: where the time
goes), the CPU's and the GPU's ratio tables in ``bench_cpu.py`` and ``bench_gpu.py``.

Whole-run speeds move by 5-15% between repetitions on a shared machine, so each is the
median of ``--repeats`` runs, interleaved so that a slow spell hits every contender.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import torch

from bench_cpu import cpu_measurements
from bench_gpu import gpu_measurements
from bench_measure import WARMUP

# what another script adds to a file this one writes: gpu_checks.py's results, in
# bench_gpu.json beside --gpu-only's measurements
KEPT_SECTIONS = ("gpu_checks",)


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
    kept = {}
    if out.is_file():
        try:
            previous = json.loads(out.read_text())
        except json.JSONDecodeError:
            previous = {}
        kept = {k: previous[k] for k in KEPT_SECTIONS if k in previous}
    out.write_text(
        json.dumps(
            {
                **kept,
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
    began = time.perf_counter()
    results, rows, where_time_goes = cpu_measurements(steps, repeats)
    if torch.cuda.is_available():  # the GPU path, when there is one, beside the CPU's
        gpu_results, gpu_rows = gpu_measurements(steps, repeats)
        results.update(gpu_results)
        rows += gpu_rows
    results["bench_wall_s"] = time.perf_counter() - began
    report(args.out, "nox -s bench", steps, repeats, results, rows, **where_time_goes)
    print("\nwhere the harness's twin-Q SAC update spends its time (self CPU time):")
    for row in where_time_goes["twin_q_update_profile"]:
        print(f"  {row['op']:40} {100 * row['share']:5.1f}%  {row['calls_per_update']:5.1f} calls")
    print("\nwhere the harness's twin-Q SAC run spends its time (share of wall time):")
    for name, share in where_time_goes["twin_q_run_time_split"].items():
        print(f"  {name:48} {100 * share:5.1f}%")
    print("\nwhere the harness's PPO run spends its time (share of wall time):")
    for name, share in where_time_goes["ppo_time_split"].items():
        print(f"  {name:40} {100 * share:5.1f}%")
    print(f"\nwritten: {args.out} ({results['bench_wall_s']:.0f} s)")


if __name__ == "__main__":
    main()
