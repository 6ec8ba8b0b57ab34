"""The run store's reading side: a finished run read back from its directory. It imports no
torch and runs no git, so that reports and the front door load fast and anywhere."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from replicate.errors import HarnessError
from replicate.store.measures import final_returns

CURVE_COLUMNS = [
    "step",
    "return_mean",
    "return_std",
    "returns",
    "guided_fraction",
    "gate_open",
    "train_return",
    "wall_s",
]


@dataclass
class Run:
    """A finished run, read back from its directory."""

    path: Path
    spec: dict[str, Any]
    curve: pd.DataFrame
    provenance: dict[str, Any]

    @property
    def final_return(self) -> float:
        """The mean of its evaluations over the last 10% of its budget, and at least its
        last 3 (the declared measure: ``replicate.store.measures``)."""
        steps = self.curve["step"].to_numpy(float)
        return float(final_returns(steps, self.curve["return_mean"].to_numpy(float))[0])

    @property
    def last_return(self) -> float:
        """Its single last evaluation."""
        return float(self.curve["return_mean"].iloc[-1])

    @property
    def process_rate(self) -> float | None:
        """Env steps per second of the process that trained it (a seed batch's members
        together); None where provenance recorded no rate."""
        rate = self.provenance.get("env_steps_per_s")
        if not rate:
            return None
        return float(rate) * (self.provenance.get("batch") or {}).get("size", 1)

    @property
    def trained_on_gpu(self) -> bool:
        return str(self.provenance.get("device", "cpu")).startswith("cuda")

    @property
    def guided_share(self) -> float:
        """The share of all its training steps on which a guider chose the action (NaN for
        an algorithm that does not record it)."""
        steps = np.diff(self.curve["step"].to_numpy(float))
        fractions = self.curve["guided_fraction"].to_numpy(float)[1:]
        known = np.isfinite(fractions)
        if not known.any():
            return float("nan")
        return float((fractions[known] * steps[known]).sum() / steps[known].sum())


def is_complete(run_dir: Path) -> bool:
    return (run_dir / "provenance.json").is_file() and not run_dir.name.startswith(".")


def load_run(run_dir: Path) -> Run:
    run_dir = Path(run_dir)
    if not is_complete(run_dir):
        raise HarnessError(
            f"{run_dir} is not a complete run directory",
            "point at a directory inside the run store that has provenance.json",
        )
    curve = pd.read_csv(run_dir / "curve.csv")
    if "train_return" not in curve:  # trained before the column was recorded
        curve["train_return"] = np.nan
    return Run(
        run_dir,
        json.loads((run_dir / "spec.json").read_text()),
        curve,
        json.loads((run_dir / "provenance.json").read_text()),
    )


def completed_runs(store: Path) -> list[Run]:
    """Every complete run in the store, in name order."""
    store = Path(store)
    if not store.is_dir():
        return []
    return [load_run(p) for p in sorted(store.iterdir()) if p.is_dir() and is_complete(p)]
