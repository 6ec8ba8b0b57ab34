"""Where a seed batch's checkpoint may be kept besides the store's ``.batch-<id>/``, behind one
narrow interface: the runner asks the places to fetch a batch's checkpoint before it trains
and tells them when the batch has landed; the scheduler asks what they keep (to resume a
batch whole, to estimate what is left, to say where a missing run stands). Neither knows
what a place is. A place implements ``CheckpointPlace`` (``replicate.store.place``) and is
listed in ``places``; the one the harness ships is the carry (``replicate.store.carry``:
checkpoints packed small enough to commit and carried between machines).

This module imports nothing heavy: the reports and the dry run read it.
"""

from __future__ import annotations

from pathlib import Path

from replicate.store.place import (  # noqa: F401  (the interface, re-exported)
    CHECKPOINT_FILE,
    CheckpointPlace,
    KeptCheckpoint,
)


def places() -> list[CheckpointPlace]:
    """The places the harness ships: the carry alone (imported on first use, for cost)."""
    from replicate.store.carry import CarryPlace

    return [CarryPlace()]


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
