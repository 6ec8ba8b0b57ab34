"""What a run's curve is measured by: its final return, its area under the curve and its
instability, as the paper's declaration (``replicate/declarations/drl-eg.toml``,
``[measures]``) defines them. Small pure functions of (steps, returns) arrays; the settings
are read once from the declaration, so that every report, figure and check reads one
definition.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from replicate.stats import curve_area

__all__ = ["curve_area", "final_returns", "instabilities", "last_returns", "settings"]

DECLARATIONS = Path(__file__).resolve().parents[1] / "declarations"
DEFAULT_DECLARATION = DECLARATIONS / "drl-eg.toml"


@dataclass(frozen=True)
class MeasureSettings:
    late_fraction: float = 0.10  # final return: evaluations after (1 - this) of the budget
    at_least: int = 3  # ... and at least this many of the last ones
    skip_fraction: float = 0.10  # instability: evaluations after this share of the budget


@cache
def settings(path: Path = DEFAULT_DECLARATION) -> MeasureSettings:
    """The ``[measures]`` of a declaration file."""
    with open(path, "rb") as handle:
        measures = tomllib.load(handle).get("measures", {})
    final = measures.get("final_return", {})
    unstable = measures.get("instability", {})
    return MeasureSettings(
        float(final.get("late_fraction", 0.10)),
        int(final.get("at_least", 3)),
        float(unstable.get("skip_fraction", 0.10)),
    )


def late_window(steps: np.ndarray, late_fraction: float, at_least: int) -> np.ndarray:
    """Which evaluations the final return averages: those after ``1 - late_fraction`` of the
    budget (the last step), and at least the last ``at_least``."""
    steps = np.asarray(steps, dtype=float)
    if len(steps) == 0:
        return np.zeros(0, dtype=bool)
    late = steps > steps[-1] * (1.0 - late_fraction)
    late[-min(at_least, len(steps)) :] = True
    return late


def final_returns(
    steps: np.ndarray, curves: np.ndarray, measure: MeasureSettings | None = None
) -> np.ndarray:
    """Per run (row of ``curves``), the mean of its evaluations in the late window."""
    measure = measure or settings()
    curves = np.atleast_2d(np.asarray(curves, dtype=float))
    window = late_window(steps, measure.late_fraction, measure.at_least)
    return curves[:, window].mean(axis=1)


def last_returns(steps: np.ndarray, curves: np.ndarray) -> np.ndarray:
    """Per run, its single last evaluation (the robustness reading of the final return)."""
    return np.atleast_2d(np.asarray(curves, dtype=float))[:, -1].copy()


def instability(curve: np.ndarray) -> float:
    """Sum of the drops between consecutive evaluations, over the curve's range: 0 for a
    curve that never falls, about 1 for one that gives back everything it gained once."""
    curve = np.asarray(curve, dtype=float)
    drops = np.clip(-np.diff(curve), 0.0, None).sum()
    spread = np.ptp(curve) if len(curve) else 0.0
    return float(drops / spread) if spread > 0 else 0.0


def instabilities(
    steps: np.ndarray, curves: np.ndarray, measure: MeasureSettings | None = None
) -> np.ndarray:
    """Per run, the instability of its curve after the first ``skip_fraction`` of the
    budget: the untrained policy's first fall is not instability."""
    measure = measure or settings()
    steps = np.asarray(steps, dtype=float)
    curves = np.atleast_2d(np.asarray(curves, dtype=float))
    kept = steps >= steps[-1] * measure.skip_fraction if len(steps) else steps.astype(bool)
    return np.array([instability(c[kept]) for c in curves])
