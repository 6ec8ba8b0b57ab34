"""The algorithm registry: a module registers itself with one decorator and is found by name.

Adding an algorithm takes one file in ``baselines/`` that defines a config dataclass and a
train function decorated with :func:`register`; every module in the package is imported on
first lookup, so nothing else needs editing. The train function is ``train(ctx, config)``
for one run, or with ``batchable=True`` ``train(bctx, configs)`` for a seed batch of any
size (``baselines.common.context.BatchContext``; the SAC family, on
``baselines.offpolicy``), which also serves single runs as batches of one.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from baselines.common.context import BatchContext, TrainContext
from baselines.common.device import flush_denormals


@dataclass(frozen=True)
class Algorithm:
    name: str
    config_cls: type
    train: Callable[[TrainContext, Any], Any]
    needs_demos: bool
    summary: str
    gpu: bool = False  # honours ``ctx.device``; the others always train on CPU
    # the seed-batch trainer ``train_batch(bctx, configs)``; None: one run per process
    train_batch: Callable[[BatchContext, list[Any]], Any] | None = None
    module: str = ""  # where it is defined
    # settings each member of a seed batch keeps for itself (its trainer reads them per
    # member), so runs that differ in them may share a batch: a T2 sweep trains as one
    per_member_settings: tuple[str, ...] = ()

    @property
    def batchable(self) -> bool:
        return self.train_batch is not None

    def make_config(self, overrides: dict[str, Any] | None = None) -> Any:
        """The default config with ``overrides`` applied; unknown keys raise ``KeyError``."""
        overrides = dict(overrides or {})
        known = {f.name: f for f in dataclasses.fields(self.config_cls)}
        unknown = sorted(set(overrides) - set(known))
        if unknown:
            raise KeyError(
                f"unknown hyperparameter(s) {unknown} for '{self.name}'; known: {sorted(known)}"
            )
        return self.config_cls(**overrides)


_REGISTRY: dict[str, Algorithm] = {}
_discovered = False


def register(
    name: str,
    config_cls: type,
    needs_demos: bool = False,
    gpu: bool = False,
    batchable: bool = False,
    per_member_settings: tuple[str, ...] = (),
) -> Callable[[Callable], Callable]:
    """Decorator for an algorithm's train function: ``train(ctx, config)``, or with
    ``batchable`` ``train(bctx, configs)``; ``per_member_settings``: config fields a seed
    batch's members may differ in (each member reads its own)."""

    def wrap(train: Callable) -> Callable:
        if name in _REGISTRY and _REGISTRY[name].module != train.__module__:
            raise ValueError(f"algorithm '{name}' registered twice")
        summary = (train.__doc__ or "").strip().splitlines()[0] if train.__doc__ else ""
        batch = _flushing_denormals(train) if batchable else None
        one_run = _batch_of_one(batch) if batch is not None else _flushing_denormals(train)
        _REGISTRY[name] = Algorithm(
            name,
            config_cls,
            one_run,
            needs_demos,
            summary,
            gpu,
            batch,
            train.__module__,
            per_member_settings,
        )
        return train

    return wrap


def _batch_of_one(train_batch: Callable) -> Callable[[TrainContext, Any], Any]:
    """One run of a batchable algorithm: a batch of one, whose failure is the run's."""

    def train(ctx: TrainContext, config: Any) -> Any:
        failures: dict[int, str] = {}
        result = train_batch(BatchContext.of_one(ctx, failures.__setitem__), [config])
        if failures:
            raise FloatingPointError(failures[0])
        return result

    return train


def _flushing_denormals(train: Callable) -> Callable:
    """``train`` with denormal floats flushed to zero while it runs (why: flush_denormals)."""

    @functools.wraps(train)
    def flushed(*args: Any, **kwargs: Any) -> Any:
        with flush_denormals():
            return train(*args, **kwargs)

    return flushed


def batched_trainer(name: str) -> Callable | None:
    """The seed-batch trainer of ``name``, or None where it has none (PPO, DDPGfD)."""
    return get_algorithm(name).train_batch


def batchable_algorithms() -> list[str]:
    """The algorithms that train in seed batches, sorted: what messages and help texts name."""
    return sorted(name for name, algorithm in algorithms().items() if algorithm.batchable)


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    import baselines

    for module in pkgutil.iter_modules(baselines.__path__):
        if not module.ispkg and module.name != "registry":
            importlib.import_module(f"baselines.{module.name}")
    _discovered = True


def algorithms() -> dict[str, Algorithm]:
    """Every registered algorithm, by name."""
    _discover()
    return dict(_REGISTRY)


class UnknownAlgorithmError(ValueError):
    pass


def get_algorithm(name: str) -> Algorithm:
    known = algorithms()
    if name not in known:
        raise UnknownAlgorithmError(
            f"unknown algorithm '{name}'; known algorithms: {', '.join(sorted(known))}"
        )
    return known[name]
