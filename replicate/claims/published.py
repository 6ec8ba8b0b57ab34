"""Published SAC returns on the MuJoCo envs, drawn beside the harness's own SAC, in two
groups: the same algorithm as ours and the paper's (SAC with a V network, "SAC v1":
Spinning Up, Coach with the SAC paper's settings, the SAC authors' code in the TD3 paper)
and modern SAC (twin Q networks, a learned temperature: Tianshou, SB3 zoo, CleanRL).

The numbers and their sources are in ``data/published/sac_v1_mujoco.csv`` and
``data/published/sac_mujoco.csv``. They were measured on -v1, -v2 or -v3 envs, whose details
differ from Gymnasium's -v5 (Ant's observation, healthy ranges): references, not targets.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources
from io import StringIO

import pandas as pd

from replicate.claims.words import count_seeds

ENV_NAMES = {
    "Hopper-v5": "Hopper",
    "Walker2d-v5": "Walker2d",
    "HalfCheetah-v5": "HalfCheetah",
    "Ant-v5": "Ant",
}
SAME_ALGORITHM = "V-network SAC"  # the paper's algorithm, as ours
MODERN = "twin-Q SAC"  # modern SAC: another algorithm in another configuration
FAMILY_TITLES = {
    SAME_ALGORITHM: "V-network SAC: the paper's algorithm, as ours",
    MODERN: "Twin-Q SAC: modern SAC, another algorithm",
}


@dataclass(frozen=True)
class Source:
    name: str
    family: str
    env_version: str
    settings: str  # network, learning rate, start steps, in a few words
    statistic: str  # what the number is


SOURCES = {
    "spinningup": Source(
        "Spinning Up",
        SAME_ALGORITHM,
        "-v2",
        "V and two Q networks, fixed temperature 0.2, lr 1e-3, 10,000 random start steps",
        "mean of 10 seeds",
    ),
    "coach": Source(
        "Coach",
        SAME_ALGORITHM,
        "-v2",
        "the SAC paper's settings: lr 3e-4, reward scale 5, 10,000 random start steps",
        "mean of 3 seeds, read off plots (+-10%)",
    ),
    "td3-paper": Source(
        "TD3 paper (SAC authors' code)",
        SAME_ALGORITHM,
        "-v1",
        "the SAC authors' code and settings",
        "maximum of the mean return within 1M steps, 10 seeds",
    ),
    "tianshou": Source(
        "Tianshou",
        MODERN,
        "-v3",
        "twin Q, learned temperature, lr 1e-3, 10,000 random start steps",
        "mean of 10 seeds",
    ),
    "sb3-zoo": Source(
        "SB3 zoo",
        MODERN,
        "-v3",
        "twin Q, learned temperature, lr 3e-4, 10,000 random start steps",
        "one seed",
    ),
    "cleanrl": Source(
        "CleanRL",
        MODERN,
        "-v2",
        "twin Q, learned temperature, critic lr 1e-3, 5,000 random start steps",
        "training-episode return",
    ),
}
FILES = ("data/published/sac_v1_mujoco.csv", "data/published/sac_mujoco.csv")


@dataclass(frozen=True)
class PublishedPoint:
    source: str
    env_id: str  # the harness's env id; the published run used the source's env version
    steps: int
    mean: float
    std: float
    seeds: int | None

    @property
    def about(self) -> Source:
        return SOURCES[self.source]

    @property
    def family(self) -> str:
        return self.about.family

    @property
    def label(self) -> str:
        seeds = f", {count_seeds(self.seeds)}" if self.seeds else ""
        return (
            f"{self.about.name} {self.family} "
            f"({ENV_NAMES[self.env_id]}{self.about.env_version}{seeds})"
        )


@functools.cache  # the files are read once per process
def published_sac() -> tuple[PublishedPoint, ...]:
    by_name = {name: env_id for env_id, name in ENV_NAMES.items()}
    points = []
    for file in FILES:
        text = resources.files("replicate").joinpath(file).read_text()
        table = pd.read_csv(StringIO(text), comment="#")
        points += [
            PublishedPoint(
                row.source,
                by_name[row.env],
                int(row.env_steps),
                float(row.return_mean),
                float("nan") if pd.isna(row.return_std) else float(row.return_std),
                None if pd.isna(row.seeds) else int(row.seeds),
            )
            for row in table.itertuples()
            if row.env in by_name
        ]
    return tuple(points)


def published_points(env_id: str, max_steps: int) -> list[PublishedPoint]:
    """The published points of ``env_id`` within a budget of ``max_steps``."""
    return [p for p in published_sac() if p.env_id == env_id and p.steps <= max_steps]


def compare_with_published(env_id: str, steps: int, ours: float) -> str | None:
    """How our SAC's mean at ``steps`` stands against each group of published SAC at the same
    steps, in words computed from the numbers; None without published points there."""
    at = [
        p for p in published_points(env_id, steps) if p.steps == steps and p.source != "td3-paper"
    ]  # the TD3 paper gives a maximum within 1M, not a curve
    parts = []
    for family in (SAME_ALGORITHM, MODERN):
        group = sorted((p for p in at if p.family == family), key=lambda p: p.mean)
        if not group:
            continue
        low, high = group[0], group[-1]
        names = (
            f"{low.about.name} {low.mean:.0f}"
            if low is high
            else f"{low.about.name} {low.mean:.0f} to {high.about.name} {high.mean:.0f}"
        )
        if ours < low.mean:
            where = f"below {family} ({names})"
        elif ours > high.mean:
            where = f"above {family} ({names})"
        else:
            where = f"within the range of {family} ({names})"
        parts.append(where)
    if not parts:
        return None
    return f"{env_id} at {steps:,} steps, our SAC {ours:.0f}: " + "; ".join(parts)


# The targets for the harness's experts (the demonstrations' mean return): within or just
# below the range that published twin-Q SAC (SB3 zoo, CleanRL, Tianshou) reaches at 1M steps
# (replicate/data/published/sac_mujoco.csv has the sources).
EXPERT_TARGETS = {
    "Hopper-v5": 3000.0,
    "Walker2d-v5": 4000.0,
    "HalfCheetah-v5": 9000.0,
    "Ant-v5": 4000.0,
}
