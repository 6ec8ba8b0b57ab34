"""A run spec: everything that determines one training run, and its content address."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from envs import env_spec
from replicate.errors import HarnessError

if TYPE_CHECKING:
    from replicate.demos import Demonstrations


@dataclass(frozen=True)
class RunSpec:
    algo: str
    env_id: str
    seed: int
    total_steps: int
    eval_interval: int
    eval_episodes: int = 5
    hyperparameters: dict[str, Any] = field(default_factory=dict)
    demos: str | None = None  # path; None means the committed demonstrations of the env

    def validate(self) -> None:
        """Raise a one-line :class:`HarnessError` for values no run could use."""
        from baselines.registry import UnknownAlgorithmError, get_algorithm
        from envs import UnknownEnvError

        try:
            get_algorithm(self.algo)
        except UnknownAlgorithmError as exc:
            raise HarnessError(str(exc), "pass --algo with one of the names listed") from None
        try:
            env_spec(self.env_id)
        except UnknownEnvError as exc:
            raise HarnessError(str(exc), "pass --env with one of the ids listed") from None
        if self.total_steps <= 0:
            raise HarnessError(
                f"step count must be positive, got {self.total_steps}", "pass --steps N with N > 0"
            )
        if self.eval_interval <= 0 or self.eval_episodes <= 0:
            raise HarnessError(
                f"evaluation interval and episodes must be positive, got "
                f"{self.eval_interval} and {self.eval_episodes}",
                "pass --eval-interval and --eval-episodes above 0",
            )
        if self.seed < 0:
            raise HarnessError(f"seed must be >= 0, got {self.seed}", "pass --seed 0 or above")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def spec_hash(resolved: dict[str, Any]) -> str:
    """SHA-256 of the canonical JSON of a resolved spec (hyperparameters with defaults filled
    in, demonstrations by content hash rather than path)."""
    canonical = json.dumps(resolved, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(canonical.encode()).hexdigest()


@dataclass
class PreparedRun:
    """A spec made ready to train: its resolved settings, config, demonstrations and address."""

    spec: RunSpec
    resolved: dict[str, Any]
    config: Any
    demos: Demonstrations | None
    run_id: str

    def directory(self, store: Path) -> Path:
        return Path(store) / self.run_id
