"""Asking the run store for runs: by a grid's specs (their exact addresses), or by a cell
(algorithm, env, budget, settings) over whatever seeds are there. A cell never mixes runs
whose specs differ in more than the seed: the threshold ablation's T2 points on Ant are
cells of their own, not seeds of Fig. 3's DRL-EG cell.

    runs, absent = runs_of(grid_specs, store)          # what a figure's grid has and lacks
    runs = find_runs(store, Cell("drl-eg", "Ant-v5", total_steps=200_000,
                                 settings={"guide_threshold": 0.5}))
    for key, members in cells(runs).items(): ...       # one list per spec-but-seed
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from replicate.store.runs import Run, completed_runs, is_complete, load_run
from replicate.store.spec import RunSpec

SEED_FIELD = "seed"
# what differs between the seeds of one cell: the seed, and the address computed from it
PER_SEED_FIELDS = (SEED_FIELD, "spec_hash")


@dataclass(frozen=True)
class Cell:
    """Which runs to find: every field left None matches anything; ``settings`` are
    hyperparameters that must have these values; ``seeds`` a range of seeds (half-open)."""

    algo: str | None = None
    env_id: str | None = None
    total_steps: int | None = None
    eval_interval: int | None = None
    settings: Mapping[str, Any] = field(default_factory=dict)
    seeds: tuple[int, int] | None = None

    def matches(self, spec: Mapping[str, Any]) -> bool:
        fields = ("algo", "env_id", "total_steps", "eval_interval")
        if any(getattr(self, f) is not None and spec[f] != getattr(self, f) for f in fields):
            return False
        hyper = spec.get("hyperparameters", {})
        if any(hyper.get(k) != v for k, v in self.settings.items()):
            return False
        return self.seeds is None or self.seeds[0] <= spec[SEED_FIELD] < self.seeds[1]


def runs_of(specs: Iterable[RunSpec], store: Path) -> tuple[list[Run], list[RunSpec]]:
    """The complete runs of ``specs`` in the store, in the order of ``specs``, and the specs
    whose run is not there yet (a spec resolves to its address before it is looked up)."""
    from replicate.store.runner import prepare  # resolving a spec loads torch: only here

    runs, absent = [], []
    for spec in specs:
        directory = prepare(spec).directory(Path(store))
        if is_complete(directory):
            runs.append(load_run(directory))
        else:
            absent.append(spec)
    return runs, absent


def stored_runs(specs: Iterable[RunSpec], store: Path) -> list[Run]:
    """The complete runs of ``specs`` in the store (nothing is trained)."""
    return runs_of(specs, store)[0]


def find_runs(store: Path, cell: Cell) -> list[Run]:
    """The store's complete runs that ``cell`` matches, sorted by seed (then name)."""
    return select(completed_runs(Path(store)), cell)


def select(runs: Iterable[Run], cell: Cell) -> list[Run]:
    """Those of ``runs`` that ``cell`` matches, sorted by seed (then name): for several
    questions to one store, read it once with ``completed_runs``."""
    found = [run for run in runs if cell.matches(run.spec)]
    return sorted(found, key=lambda run: (run.spec[SEED_FIELD], run.path.name))


def cell_key(spec: Mapping[str, Any]) -> str:
    """A run's cell: its spec less its seed (and address), as one comparable string."""
    rest = {k: v for k, v in spec.items() if k not in PER_SEED_FIELDS}
    return json.dumps(rest, sort_keys=True, default=str)


def cells(runs: Iterable[Run]) -> dict[str, list[Run]]:
    """Runs by cell (spec less seed), each sorted by seed, in order of first appearance."""
    grouped: dict[str, list[Run]] = {}
    for run in runs:
        grouped.setdefault(cell_key(run.spec), []).append(run)
    for members in grouped.values():
        members.sort(key=lambda run: run.spec[SEED_FIELD])
    return grouped
