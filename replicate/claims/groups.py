"""The store's runs as the claims read them: grouped by (env, algorithm), their curves on
the evaluation steps all of a group's runs share, and the declared measures over them."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pandas as pd

from replicate.claims.checks import Group
from replicate.errors import HarnessError
from replicate.store.measures import final_returns, last_returns
from replicate.store.query import cells
from replicate.store.runs import Run


def group_runs(runs: list[Run]) -> dict[tuple[str, str], list[Run]]:
    """Runs by (env, algorithm), each sorted by seed. The runs of one group must differ only
    in seed: runs of other settings (an ablation's T2 points, another budget) are cells of
    their own, and judging them as seeds of one cell fails here, in one line."""
    groups: dict[tuple[str, str], list[Run]] = defaultdict(list)
    for run in runs:
        groups[(run.spec["env_id"], run.spec["algo"])].append(run)
    for (env_id, algo), members in groups.items():
        if len(cells(members)) > 1:
            raise HarnessError(
                f"{algo} on {env_id}: runs of {len(cells(members))} different settings would "
                "be judged as seeds of one cell",
                "ask the run store for the grid's runs (replicate.store.query.runs_of)",
            )
        members.sort(key=lambda r: r.spec["seed"])
    return dict(groups)


def curve_matrix(runs: list[Run], column: str = "return_mean") -> tuple[np.ndarray, np.ndarray]:
    """(steps, returns[runs, steps]) over the evaluation steps that every run shares;
    ``column``: the evaluations' mean return, or ``train_return`` (training episodes)."""
    common = sorted(set.intersection(*(set(r.curve["step"]) for r in runs)))
    matrix = np.stack([r.curve.set_index("step").loc[common, column].to_numpy(float) for r in runs])
    return np.asarray(common), matrix


def training_rates(members: list[Run]) -> dict[str, float]:
    """Env steps per second of one training process (a seed batch's members together), by
    device kind, median over the runs: what more seeds of this cell would cost."""
    by_kind: dict[str, list[float]] = defaultdict(list)
    for run in members:
        if run.process_rate is not None:
            by_kind["gpu" if run.trained_on_gpu else "cpu"].append(run.process_rate)
    return {kind: float(np.median(rates)) for kind, rates in by_kind.items()}


READINGS = ("evaluations", "last evaluation", "training episodes")


def claim_groups(runs: list[Run], reading: str = "evaluations") -> dict[tuple[str, str], Group]:
    """The runs of each (env, algorithm) as the claims ledger reads them: the declared
    measures over the evaluation curves; or, for the robustness line, the final return as
    the single last evaluation, or every measure over the training episodes' returns
    (cells whose runs record none are left out)."""
    groups = {}
    for (env_id, algo), members in group_runs(runs).items():
        column = "train_return" if reading == "training episodes" else "return_mean"
        steps, matrix = curve_matrix(members, column)
        if reading == "training episodes":
            # the first point precedes any training episode; between episode ends the last
            # finished episode's return stands; a cell with a run that records none is left out
            steps, matrix = steps[1:], matrix[:, 1:]
            if not len(steps) or not np.isfinite(matrix).any(axis=1).all():
                continue
            matrix = pd.DataFrame(matrix.T).ffill().bfill().to_numpy().T
        finals = last_returns(steps, matrix) if reading == "last evaluation" else None
        groups[(env_id, algo)] = Group(
            env_id,
            algo,
            [r.spec["seed"] for r in members],
            final_returns(steps, matrix) if finals is None else finals,
            matrix,
            steps,
            training_rates(members),
        )
    return groups
