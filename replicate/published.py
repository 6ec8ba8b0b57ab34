"""Published SAC returns on the MuJoCo envs, drawn beside the harness's own SAC.

The numbers and their sources are in ``data/published/sac_mujoco.csv`` (Tianshou's benchmark
with 10 seeds at several budgets; SB3 zoo and CleanRL at 1M). They were measured on the
-v3 (Tianshou, SB3) and -v2 (CleanRL) envs, whose details differ from Gymnasium's -v5
(Ant's observation, healthy ranges), so they are a reference, not a target.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from io import StringIO

import pandas as pd

from replicate.templating import count_seeds

ENV_NAMES = {"Hopper-v5": "Hopper", "Walker2d-v5": "Walker2d", "HalfCheetah-v5": "HalfCheetah",
             "Ant-v5": "Ant"}
ENV_VERSIONS = {"tianshou": "-v3", "sb3-zoo": "-v3", "cleanrl": "-v2"}


@dataclass(frozen=True)
class PublishedPoint:
    source: str
    env_id: str  # the harness's env id; the published run used ENV_VERSIONS[source]
    steps: int
    mean: float
    std: float
    seeds: int | None

    @property
    def label(self) -> str:
        seeds = f", {count_seeds(self.seeds)}" if self.seeds else ""
        return f"{self.source} SAC ({ENV_NAMES[self.env_id]}{ENV_VERSIONS[self.source]}{seeds})"


def published_sac() -> list[PublishedPoint]:
    text = resources.files("replicate").joinpath("data/published/sac_mujoco.csv").read_text()
    table = pd.read_csv(StringIO(text), comment="#")
    by_name = {name: env_id for env_id, name in ENV_NAMES.items()}
    return [PublishedPoint(row.source, by_name[row.env], int(row.env_steps),
                           float(row.return_mean), float(row.return_std),
                           None if pd.isna(row.seeds) else int(row.seeds))
            for row in table.itertuples() if row.env in by_name]


def published_points(env_id: str, max_steps: int) -> list[PublishedPoint]:
    """The published points of ``env_id`` within a budget of ``max_steps``."""
    return [p for p in published_sac() if p.env_id == env_id and p.steps <= max_steps]
