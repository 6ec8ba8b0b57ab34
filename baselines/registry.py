"""The algorithm registry: a module registers itself with one decorator and is found by name.

Adding an algorithm takes one file in ``baselines/`` that defines a config dataclass and a
``train(ctx, config)`` function decorated with :func:`register`; every module in the package
is imported on first lookup, so nothing else needs editing.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from baselines.common.context import TrainContext
from baselines.common.device import flush_denormals


@dataclass(frozen=True)
class Algorithm:
    name: str
    config_cls: type
    train: Callable[[TrainContext, Any], Any]
    needs_demos: bool
    summary: str
    gpu: bool = False  # honours ``ctx.device``; the others always train on CPU

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
    name: str, config_cls: type, needs_demos: bool = False, gpu: bool = False
) -> Callable[[Callable], Callable]:
    """Decorator for an algorithm's ``train`` function."""

    def wrap(train: Callable) -> Callable:
        registered = _REGISTRY[name].train if name in _REGISTRY else None
        if registered is not None and getattr(registered, "__wrapped__", None) is not train:
            raise ValueError(f"algorithm '{name}' registered twice")
        summary = (train.__doc__ or "").strip().splitlines()[0] if train.__doc__ else ""
        _REGISTRY[name] = Algorithm(
            name, config_cls, _flushing_denormals(train), needs_demos, summary, gpu
        )
        return train

    return wrap


def _flushing_denormals(train: Callable) -> Callable:
    """``train`` with denormal floats flushed to zero while it runs (why: flush_denormals)."""

    @functools.wraps(train)
    def flushed(*args: Any, **kwargs: Any) -> Any:
        with flush_denormals():
            return train(*args, **kwargs)

    return flushed


_BATCHED: dict[str, Callable] = {}


def register_batched(name: str) -> Callable[[Callable], Callable]:
    """Decorator for a seed-batched trainer of algorithm ``name``: ``train(bctx, configs)``
    trains the members of a ``baselines.batched.BatchContext`` together."""

    def wrap(train: Callable) -> Callable:
        _BATCHED[name] = _flushing_denormals(train)
        return train

    return wrap


def batched_trainer(name: str) -> Callable | None:
    """The seed-batched trainer of ``name``, or None where it has none (PPO, DDPGfD)."""
    _discover()
    return _BATCHED.get(name)


def batchable_algorithms() -> list[str]:
    """The algorithms that have a seed-batched trainer, sorted: what messages and help
    texts name."""
    _discover()
    return sorted(_BATCHED)


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
