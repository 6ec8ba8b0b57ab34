"""What a checkpoint place is: where a seed batch's checkpoint may be kept besides the store's
``.batch-<id>/`` (the interface ``replicate.store.checkpoint_places`` asks), and what it
keeps. This module imports nothing heavy."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

CHECKPOINT_FILE = "checkpoint.pt"  # a batch's checkpoint in the store: .batch-<id>/checkpoint.pt


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
