"""Where a seed batch's checkpoint may be kept besides the store's ``.batch-<id>/``, behind one
narrow interface: the runner asks the places to fetch a batch's checkpoint before it trains
and tells them when the batch has landed; the scheduler asks what they keep (to resume a
batch whole, to estimate what is left, to say where a missing run stands). Neither knows
what a place is. A place is a module listed in ``PLACE_MODULES`` that calls ``register``;
the one the harness ships is ``replicate.store.carry`` (checkpoints packed small enough to commit
and carried between machines).

This module imports nothing heavy: the reports and the dry run read it.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

CHECKPOINT_FILE = "checkpoint.pt"  # a batch's checkpoint in the store: .batch-<id>/checkpoint.pt
PLACE_MODULES = ("replicate.store.carry",)


@dataclass(frozen=True)
class KeptCheckpoint:
    """A checkpoint kept by a place: of seed batch ``name`` (a run alone is a batch of one)
    with run ids ``members``, at env step ``step`` per member."""

    name: str
    members: tuple[str, ...]
    step: int
    where: Path  # the place's directory, for messages
    note: str  # when and where it was kept, in a few words


class CheckpointPlace(Protocol):
    def kept(self, store: Path) -> list[KeptCheckpoint]:
        """What the place keeps for ``store``."""
        ...

    def fetch(self, store: Path, name: str, checkpoint: Path) -> None:
        """Put batch ``name``'s kept checkpoint at ``checkpoint`` if there is none there or
        the kept one is further on."""
        ...

    def landed(self, store: Path, names: list[str]) -> None:
        """Batch or run ``names`` landed in the store: keep nothing more of them."""
        ...

    def tidy(self, store: Path) -> None:
        """Forget what is kept of batches of which a run landed by another way."""
        ...


_PLACES: list[CheckpointPlace] = []


def register(place: CheckpointPlace) -> CheckpointPlace:
    if place not in _PLACES:
        _PLACES.append(place)
    return place


def places() -> list[CheckpointPlace]:
    for module in PLACE_MODULES:
        importlib.import_module(module)
    return list(_PLACES)


def kept(store: Path | None) -> list[KeptCheckpoint]:
    """Every checkpoint kept for ``store`` by any place."""
    if store is None:
        return []
    return [k for place in places() for k in place.kept(Path(store))]


def fetch(store: Path, name: str, checkpoint: Path) -> None:
    for place in places():
        place.fetch(Path(store), name, checkpoint)


def landed(store: Path, names: list[str]) -> None:
    for place in places():
        place.landed(Path(store), names)


def tidy(store: Path) -> None:
    for place in places():
        place.tidy(Path(store))


def resumable_steps(store: Path | None, run_ids: set[str], batches: bool = True) -> dict[str, int]:
    """Each of ``run_ids`` that resumes from a kept checkpoint, with the step it resumes at:
    the members of every kept batch whose runs are all among ``run_ids`` (a batch resumes
    only whole); ``batches`` False: of kept single runs only (an executor that trains one run
    per task starts a larger kept batch over)."""
    return {
        run_id: k.step
        for k in kept(store)
        if set(k.members) <= run_ids and (batches or len(k.members) == 1)
        for run_id in k.members
    }
