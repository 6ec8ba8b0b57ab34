"""Runner and run store: one RunSpec in, one complete run directory out.

A run directory is named by the algorithm, env, seed and a hash of the resolved spec. It is
built under a temporary name and renamed into place only when training finished, so a
directory with the final name is always complete, and a crashed or interrupted run leaves
nothing that looks finished (its temporary directory is removed where possible).

Files of a run:
    spec.json        the resolved spec: hyperparameters with defaults, demonstration hash
    curve.csv        the evaluation curve (env steps, return of each test episode, ...)
    provenance.json  versions, git revision, machine, seed, wall time, env steps per second
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from baselines.common.context import EvalPoint, TrainContext
from baselines.registry import get_algorithm
from replicate import provenance
from replicate.demos import Demonstrations, default_demo_path, load_demos
from replicate.errors import HarnessError
from replicate.spec import RunSpec, spec_hash

CURVE_COLUMNS = ["step", "return_mean", "return_std", "returns", "guided_fraction", "gate_open",
                 "wall_s"]


@dataclass
class Run:
    """A finished run, read back from its directory."""

    path: Path
    spec: dict[str, Any]
    curve: pd.DataFrame
    provenance: dict[str, Any]

    @property
    def final_return(self) -> float:
        return float(self.curve["return_mean"].iloc[-1])


@dataclass
class PreparedRun:
    spec: RunSpec
    resolved: dict[str, Any]
    config: Any
    demos: Demonstrations | None
    run_id: str

    def directory(self, store: Path) -> Path:
        return Path(store) / self.run_id


def prepare(spec: RunSpec) -> PreparedRun:
    """Validate ``spec``, load its demonstrations, resolve defaults and compute its address."""
    spec.validate()
    algorithm = get_algorithm(spec.algo)
    try:
        config = algorithm.make_config(spec.hyperparameters)
    except (KeyError, TypeError, ValueError) as exc:
        raise HarnessError(f"bad hyperparameters for {spec.algo}: {exc}".replace("\n", " "),
                           "check the --set KEY=VALUE options against `--algo` defaults") from None
    demos = None
    demo_info = None
    if algorithm.needs_demos:
        path = Path(spec.demos) if spec.demos else default_demo_path(spec.env_id)
        demos = load_demos(path, spec.env_id)
        demo_info = {"sha256": demos.sha256, "n_pairs": len(demos.observations),
                     "expert_return_mean": demos.mean_return, "path": str(path)}
    resolved = {
        "algo": spec.algo, "env_id": spec.env_id, "seed": spec.seed,
        "total_steps": spec.total_steps, "eval_interval": spec.eval_interval,
        "eval_episodes": spec.eval_episodes,
        "hyperparameters": dataclasses.asdict(config),
        "demos": None if demo_info is None else {k: demo_info[k] for k in ("sha256", "n_pairs")},
    }
    digest = spec_hash(resolved)
    resolved["spec_hash"] = digest
    resolved["demos_path"] = None if demo_info is None else demo_info["path"]
    run_id = f"{spec.algo}__{spec.env_id.replace('/', '-')}__s{spec.seed}__{digest[:12]}"
    return PreparedRun(spec, resolved, config, demos, run_id)


def is_complete(run_dir: Path) -> bool:
    return (run_dir / "provenance.json").is_file() and not run_dir.name.startswith(".")


def load_run(run_dir: Path) -> Run:
    run_dir = Path(run_dir)
    if not is_complete(run_dir):
        raise HarnessError(f"{run_dir} is not a complete run directory",
                           "point at a directory inside the run store that has provenance.json")
    return Run(run_dir, json.loads((run_dir / "spec.json").read_text()),
               pd.read_csv(run_dir / "curve.csv"),
               json.loads((run_dir / "provenance.json").read_text()))


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    path.write_text(json.dumps(payload, indent=2, sort_keys=True, default=str) + "\n")


def execute(prepared: PreparedRun, store: Path,
            on_steps: Callable[[int], None] = lambda n: None) -> Run:
    """Train ``prepared`` into the store unless a complete run with its address exists."""
    store = Path(store)
    final_dir = prepared.directory(store)
    if is_complete(final_dir):
        return load_run(final_dir)
    store.mkdir(parents=True, exist_ok=True)
    tmp_dir = store / f".partial-{prepared.run_id}-{os.getpid()}"
    shutil.rmtree(tmp_dir, ignore_errors=True)
    tmp_dir.mkdir()
    try:
        _train_into(prepared, tmp_dir, on_steps)
        if final_dir.exists():  # a stale incomplete directory of the same address
            shutil.rmtree(final_dir)
        os.replace(tmp_dir, final_dir)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
    return load_run(final_dir)


def _train_into(prepared: PreparedRun, run_dir: Path, on_steps: Callable[[int], None]) -> None:
    spec = prepared.spec
    _write_json(run_dir / "spec.json", prepared.resolved)
    started = time.time()
    started_iso = datetime.now(timezone.utc).isoformat(timespec="seconds")
    curve_file = open(run_dir / "curve.csv", "w", newline="")
    writer = csv.writer(curve_file)
    writer.writerow(CURVE_COLUMNS)

    def on_eval(point: EvalPoint) -> None:
        writer.writerow([point.step, f"{point.mean_return:.6g}", f"{np.std(point.returns):.6g}",
                         ";".join(f"{r:.6g}" for r in point.returns),
                         f"{point.guided_fraction:.6g}",
                         "" if point.gate_open is None else int(point.gate_open),
                         f"{time.time() - started:.3f}"])
        curve_file.flush()

    ctx = TrainContext(env_id=spec.env_id, seed=spec.seed, total_steps=spec.total_steps,
                       eval_interval=spec.eval_interval, eval_episodes=spec.eval_episodes,
                       demos=prepared.demos, on_eval=on_eval, on_steps=on_steps)
    try:
        get_algorithm(spec.algo).train(ctx, prepared.config)
    finally:
        curve_file.close()
    wall = time.time() - started
    _write_json(run_dir / "provenance.json", {
        "run_id": prepared.run_id, "spec_hash": prepared.resolved["spec_hash"],
        "seed": spec.seed, "started_utc": started_iso, "wall_time_s": round(wall, 3),
        "env_steps_per_s": round(spec.total_steps / wall, 2) if wall > 0 else None,
        "git_revision": provenance.git_revision(), "versions": provenance.package_versions(),
        "machine": provenance.machine(),
        "demos": None if prepared.demos is None else {
            "sha256": prepared.demos.sha256, "path": prepared.resolved["demos_path"],
            "expert_return_mean": prepared.demos.mean_return,
            "expert": prepared.demos.metadata.get("expert")},
    })


def completed_runs(store: Path) -> list[Run]:
    """Every complete run in the store, in name order."""
    store = Path(store)
    if not store.is_dir():
        return []
    return [load_run(p) for p in sorted(store.iterdir()) if p.is_dir() and is_complete(p)]
