"""Runner and run store: one RunSpec in, one complete run directory out.

A run directory is named by the algorithm, env, seed and a hash of the resolved spec. It is
built under a hidden name (``.partial-<run id>``) and renamed into place only when training
finished, so a directory with the final name is always complete. Every run trains as a seed
batch, of one where it trains alone: the batch checkpoints into its own hidden directory
(``.batch-<id>``), and a run that was interrupted (Ctrl-C, kill -9, a lost machine, a time
limit) resumes from there when it is started again and finishes on the same curve. A run
that raised an error is recorded as failed and its hidden directories removed. A lock file
per run keeps two processes from training the same run at once.

Files of a run:
    spec.json        the resolved spec: hyperparameters with defaults, demonstration hash
    curve.csv        the evaluation curve (env steps, return of each test episode, ...)
    provenance.json  versions, git revision, machine, seed, wall time, env steps per second,
                     the trainer's code path and the seed batch it trained in
    segments.json    one entry per uninterrupted stretch of training (a run interrupted and
                     resumed once has two): start, step resumed from, wall time, device;
                     provenance.json repeats the list under "segments"
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from baselines.common.checkpoint import CheckpointDeviceError, TimeLimitReached
from baselines.common.context import BatchContext, TrainContext
from baselines.common.device import describe_device, device_kind, resolve_device, resume_device
from baselines.registry import batchable_algorithms, get_algorithm
from replicate.demos import default_demo_path, load_demos
from replicate.errors import HarnessError
from replicate.store import checkpoint_places, provenance
from replicate.store.devices import check_device  # noqa: F401  (part of the runner's interface)
from replicate.store.provenance import PROJECT_ROOT, portable_path  # noqa: F401  (interface)
from replicate.store.run_recorder import (  # noqa: F401
    SEGMENTS_FILE,
    RunRecorder,
    read_segments,
    write_json,
    write_segments,
)
from replicate.store.runs import (  # noqa: F401  (the run store's reading side, re-exported)
    CURVE_COLUMNS,
    Run,
    completed_runs,
    is_complete,
    load_run,
)
from replicate.store.spec import PreparedRun, RunSpec, spec_hash  # noqa: F401  (interface)

provenance.code_revision()  # fix the code's revision when the code is loaded


# Settings added after runs were committed: at these values they are left out of the
# resolved spec, so every run trained before a setting existed keeps its address.
ADDRESS_NEUTRAL_DEFAULTS: dict[str, Any] = {"random_start_steps": 0, "keep_best_policy": False}


def prepare(spec: RunSpec) -> PreparedRun:
    """Validate ``spec``, load its demonstrations, resolve defaults and compute its address."""
    spec.validate()
    algorithm = get_algorithm(spec.algo)
    try:
        config = algorithm.make_config(spec.hyperparameters)
    except (KeyError, TypeError, ValueError) as exc:
        raise HarnessError(
            f"bad hyperparameters for {spec.algo}: {exc}".replace("\n", " "),
            "check the --set KEY=VALUE options against `--algo` defaults",
        ) from None
    demos = None
    demo_info = None
    if algorithm.needs_demos:
        path = Path(spec.demos) if spec.demos else default_demo_path(spec.env_id)
        demos = load_demos(path, spec.env_id)
        demo_info = {
            "sha256": demos.sha256,
            "n_pairs": len(demos.observations),
            "expert_return_mean": demos.mean_return,
            "path": portable_path(path),
        }
    hyperparameters = {
        k: v
        for k, v in dataclasses.asdict(config).items()
        if ADDRESS_NEUTRAL_DEFAULTS.get(k, object()) != v
    }
    resolved = {
        "algo": spec.algo,
        "env_id": spec.env_id,
        "seed": spec.seed,
        "total_steps": spec.total_steps,
        "eval_interval": spec.eval_interval,
        "eval_episodes": spec.eval_episodes,
        "hyperparameters": hyperparameters,
        "demos": None if demo_info is None else {k: demo_info[k] for k in ("sha256", "n_pairs")},
    }
    digest = spec_hash(resolved)
    resolved["spec_hash"] = digest
    resolved["demos_path"] = None if demo_info is None else demo_info["path"]
    run_id = f"{spec.algo}__{spec.env_id.replace('/', '-')}__s{spec.seed}__{digest[:12]}"
    return PreparedRun(spec, resolved, config, demos, run_id)


DEFAULT_CHECKPOINT_INTERVAL = 10_000  # env steps; taken at the next episode end
CHECKPOINT_FILE = checkpoint_places.CHECKPOINT_FILE
BEST_POLICY_FILE = "best_policy.pt"  # runs with keep_best_policy (experts)


class RunLockedError(HarnessError):
    pass


# Errors of the numbers or the code: resuming would meet them again, so their run's hidden
# directory is removed. Anything else (a full disk, a lost machine, Ctrl-C, the time limit)
# keeps it to resume.
RECURRING_ERRORS = (
    FloatingPointError,
    ValueError,
    TypeError,
    KeyError,
    IndexError,
    AttributeError,
    RuntimeError,
    HarnessError,
)


def partial_directory(prepared: PreparedRun, store: Path) -> Path:
    return Path(store) / f".partial-{prepared.run_id}"


def execute(
    prepared: PreparedRun,
    store: Path,
    on_steps: Callable[[int], None] = lambda n: None,
    checkpoint_interval: int = DEFAULT_CHECKPOINT_INTERVAL,
    device: str = "auto",
    follow_checkpoint: bool | None = None,
    deadline: float | None = None,
) -> Run:
    """Train ``prepared`` into the store unless a complete run with its address exists;
    resume it from its checkpoint if an earlier attempt was interrupted. A run is a seed
    batch of one (``execute_batch``): one path locks, resumes, lands and records every run.
    ``device``: ``auto`` (the GPU when there is one, for algorithms with a GPU path),
    ``cpu`` or ``cuda``. A checkpoint made on the other kind of device is resumed there when
    ``follow_checkpoint`` (default: when ``device`` is ``auto``), and refused otherwise.
    ``deadline`` (a ``time.time()``): once it has passed, the run checkpoints at its next
    chance and raises ``TimeLimitReached``, its checkpoint kept for the same call to
    resume. A run whose losses diverge raises ``FloatingPointError``."""
    final_dir = prepared.directory(Path(store))
    outcome = execute_batch(
        [prepared],
        store,
        on_steps,
        checkpoint_interval,
        device,
        follow_checkpoint,
        deadline=deadline,
    )
    if outcome.failed:
        raise FloatingPointError(outcome.failed[0][1])
    return load_run(final_dir)


def _checkpoint_device(run_dir: Path, earlier_segments: list[dict]) -> str | None:
    """``cpu`` or ``cuda``: where the run's checkpoint was made (by the last part of its
    training, since a part only resumes a checkpoint of its own kind); None without a
    checkpoint. Parts from before the GPU path name no device: they ran on CPU."""
    if not (run_dir / CHECKPOINT_FILE).is_file():
        return None
    return device_kind(earlier_segments[-1].get("device", "cpu") if earlier_segments else "cpu")


def _context(
    prepared: PreparedRun, recorder: RunRecorder, device: str, **fields: Any
) -> TrainContext:
    spec = prepared.spec
    if getattr(prepared.config, "keep_best_policy", False):
        fields["best_policy_path"] = recorder.run_dir / BEST_POLICY_FILE
    return TrainContext(
        env_id=spec.env_id,
        seed=spec.seed,
        total_steps=spec.total_steps,
        eval_interval=spec.eval_interval,
        eval_episodes=spec.eval_episodes,
        demos=prepared.demos,
        on_eval=recorder.on_eval,
        on_resume=recorder.on_resume,
        device=device,
        **fields,
    )


def _batch_of_one(train: Callable[[TrainContext, Any], Any]) -> Callable[..., Any]:
    """A trainer with a loop of its own, ``train(ctx, config)``, as the trainer of a batch of
    one: the batch's progress, checkpoint and deadline become the run's."""

    def train_batch(bctx: BatchContext, configs: list[Any]) -> Any:
        (ctx,) = bctx.members
        ctx = dataclasses.replace(
            ctx,
            on_steps=bctx.on_steps,
            checkpoint_path=bctx.checkpoint_path,
            checkpoint_interval=bctx.checkpoint_interval,
            deadline=bctx.deadline,
        )
        return train(ctx, configs[0])

    return train_batch


def batch_key(prepared: PreparedRun) -> str:
    """Runs with equal keys may share a batch: everything of the resolved spec but the seed
    and the settings the algorithm keeps per member (``per_member_settings``)."""
    per_member = get_algorithm(prepared.spec.algo).per_member_settings
    resolved = {
        k: v for k, v in prepared.resolved.items() if k not in ("seed", "spec_hash", "demos_path")
    }
    resolved["hyperparameters"] = {
        k: v for k, v in resolved["hyperparameters"].items() if k not in per_member
    }
    return json.dumps(resolved, sort_keys=True, default=str)


def batch_id(members: list[PreparedRun]) -> str:
    """The address of a batch: its members' run ids, in order."""
    joined = "\n".join(p.run_id for p in members)
    return "batch-" + hashlib.sha256(joined.encode()).hexdigest()[:16]


@dataclass
class BatchOutcome:
    runs: list[Run]
    failed: list[tuple[str, str]]  # (run id, reason) of members that failed alone


def execute_batch(
    members: list[PreparedRun],
    store: Path,
    on_steps: Callable[[int], None] = lambda n: None,
    checkpoint_interval: int = DEFAULT_CHECKPOINT_INTERVAL,
    device: str = "auto",
    follow_checkpoint: bool | None = None,
    env_workers: int = 0,
    deadline: float | None = None,
) -> BatchOutcome:
    """Train ``members`` (one algorithm, one env and budget, different seeds) together in
    this process; an algorithm with a loop of its own (PPO, DDPGfD) trains batches of one.
    Each member lands in the store as its own run directory, at its own run address; its
    provenance names the batch. A member that diverges fails alone. The batch checkpoints as
    a whole into ``<store>/.<batch id>/`` and resumes from there when started again with the
    same members; past ``deadline`` it checkpoints and stops (``TimeLimitReached``)."""
    check_device(device)
    members = [p for p in members if not is_complete(p.directory(Path(store)))]
    if not members:
        return BatchOutcome([], [])
    batch = SeedBatch(members, Path(store))
    try:
        batch.claim()
        batch.open(device, device == "auto" if follow_checkpoint is None else follow_checkpoint)
        failures = batch.train(on_steps, checkpoint_interval, env_workers, deadline)
        return batch.land(failures)
    finally:
        batch.release()


class SeedBatch:
    """One seed batch's way through the store, in named steps: ``claim`` its runs (a lock
    each), ``open`` its checkpoint directory (fetched from a checkpoint place, on the device
    its checkpoint names), ``train`` it (recording each stretch), ``land`` each member that
    finished as its own run, and ``release`` the locks, whatever happened."""

    def __init__(self, members: list[PreparedRun], store: Path):
        self.members, self.store = members, store
        self.algorithm = get_algorithm(members[0].spec.algo)
        if len({batch_key(p) for p in members}) != 1 or (
            len(members) > 1 and not self.algorithm.batchable
        ):
            raise HarnessError(
                "the runs of a batch must differ only in seed and the settings their "
                f"algorithm keeps per member, and it must train in seed batches "
                f"({members[0].spec.algo})",
                f"batch only {', '.join(batchable_algorithms())} runs of one env and budget",
            )
        self.ident = batch_id(members)
        self.directory = store / f".{self.ident}"
        self.work_dirs = [partial_directory(p, store) for p in members]
        self.locks: list[tuple[Path, Any]] = []
        self.device = "cpu"
        self.earlier: list[dict] = []
        self.recorders: list[RunRecorder] = []

    def claim(self) -> None:
        """Lock every member's run, failing at once (never waiting) where another process
        trains it or has just finished it."""
        self.store.mkdir(parents=True, exist_ok=True)
        for p in self.members:
            lock_path = self.store / f".lock-{p.run_id}"
            handle = open(lock_path, "w")
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                handle.close()  # the lock file is its holder's to remove
                raise RunLockedError(
                    f"run {p.run_id} is being trained by another process",
                    "wait for it, or stop that process",
                ) from None
            self.locks.append((lock_path, handle))
            replaced = (
                not lock_path.exists()
                or os.stat(lock_path).st_ino != os.fstat(handle.fileno()).st_ino
            )
            if replaced or is_complete(p.directory(self.store)):
                raise RunLockedError(
                    f"run {p.run_id} was just finished by another process",
                    "run the same command again",
                )

    def open(self, device: str, follow_checkpoint: bool) -> None:
        """The batch's directory with its checkpoint, if one is kept anywhere, and the device
        to train on: the one asked for, or the checkpoint's kind when following it."""
        self.directory.mkdir(exist_ok=True)
        names = json.dumps([p.run_id for p in self.members]) + "\n"
        (self.directory / "members.json").write_text(names)
        checkpoint_places.fetch(self.store, self.ident, self.directory / CHECKPOINT_FILE)
        self.earlier = read_segments(self.directory)
        resolved = resolve_device(device, has_gpu_path=self.algorithm.gpu)
        try:
            self.device = resume_device(
                resolved,
                _checkpoint_device(self.directory, self.earlier),
                follow_checkpoint,
                what=f"batch {self.ident} ({self.directory})",
            )
        except CheckpointDeviceError as exc:
            raise self._device_error(exc) from None
        # this stretch is recorded before training: a checkpoint it leaves names its device
        self.record_stretch(0.0)

    def record_stretch(self, wall_time_s: float) -> None:
        this = {"wall_time_s": wall_time_s, "device": describe_device(self.device)}
        write_segments(self.directory, self.earlier + [this])

    def train(
        self,
        on_steps: Callable[[int], None],
        checkpoint_interval: int,
        env_workers: int,
        deadline: float | None,
    ) -> dict[int, str]:
        """Train the batch to its end; returns the members that failed alone, by index."""
        info = {
            "id": self.ident,
            "size": len(self.members),
            "members": [p.run_id for p in self.members],
        }
        for p, work in zip(self.members, self.work_dirs):
            work.mkdir(exist_ok=True)
            self.recorders.append(RunRecorder(p, work, self.device, info))
        failures: dict[int, str] = {}
        bctx = BatchContext(
            [_context(p, r, self.device) for p, r in zip(self.members, self.recorders)],
            device=self.device,
            env_workers=env_workers,
            on_steps=on_steps,
            on_resume=lambda step: [r.on_resume(step) for r in self.recorders],
            on_member_failed=failures.__setitem__,
            checkpoint_path=self.directory / CHECKPOINT_FILE,
            checkpoint_interval=checkpoint_interval,
            deadline=deadline,
        )
        trainer = self.algorithm.train_batch or _batch_of_one(self.algorithm.train)
        started = time.time()
        for recorder in self.recorders:
            recorder.open()
        try:
            trainer(bctx, [p.config for p in self.members])
        except TimeLimitReached:  # each stretch's wall time up to the stop; the checkpoint stays
            self.record_stretch(round(time.time() - started, 3))
            for recorder in self.recorders:
                recorder.record_segment()
            raise
        except CheckpointDeviceError as exc:
            raise self._device_error(exc) from None
        except torch.OutOfMemoryError:
            raise HarnessError(
                f"batch {self.ident} of {len(self.members)} run(s) ran out of GPU memory; "
                "its last checkpoint is kept",
                "run the same command again with a smaller --batch"
                if len(self.members) > 1
                else "run the same command again with fewer --gpu-workers, or with --device cpu",
            ) from None
        except RECURRING_ERRORS:
            shutil.rmtree(self.directory, ignore_errors=True)
            for work in self.work_dirs:
                shutil.rmtree(work, ignore_errors=True)
            raise  # a carried checkpoint stays: the failure may be this machine's
        finally:
            for recorder in self.recorders:
                recorder.close()
        self.record_stretch(round(time.time() - started, 3))
        return failures

    def land(self, failures: dict[int, str]) -> BatchOutcome:
        """Each member that finished becomes a complete run under its address; the batch's
        directory goes, and the checkpoint places are told."""
        runs, failed = [], []
        for k, (p, recorder, work) in enumerate(zip(self.members, self.recorders, self.work_dirs)):
            if k in failures:
                failed.append((p.run_id, f"FloatingPointError: {failures[k]}"))
                shutil.rmtree(work, ignore_errors=True)
                continue
            recorder.finish()
            (work / CHECKPOINT_FILE).unlink(missing_ok=True)  # an earlier attempt's, if any
            final_dir = p.directory(self.store)
            if final_dir.exists():
                shutil.rmtree(final_dir)
            os.replace(work, final_dir)
            runs.append(load_run(final_dir))
        shutil.rmtree(self.directory, ignore_errors=True)
        checkpoint_places.landed(self.store, [self.ident, *(run.path.name for run in runs)])
        return BatchOutcome(runs, failed)

    def release(self) -> None:
        for lock_path, handle in self.locks:
            lock_path.unlink(missing_ok=True)
            handle.close()

    def _device_error(self, exc: CheckpointDeviceError) -> HarnessError:
        return HarnessError(
            str(exc), f"run it on the device its checkpoint names, or delete {self.directory}"
        )
