"""Training a grid: its missing runs, alone or in seed batches (``replicate.grids.planning``),
in local worker processes with one progress display, or as tasks on a Ray cluster
(``replicate.grids.ray_executor``), within the command's time limit."""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import queue
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from tqdm import tqdm

from baselines.common.checkpoint import TimeLimitReached, past
from baselines.common.device import worker_devices
from replicate.errors import HarnessError, TimeLimitStop
from replicate.grids.planning import (
    estimate_minutes,
    gpu_requested,
    plan_batches,
    print_plan,
    resolve_batch,
    task_ids,
)
from replicate.grids.profiles import GridOutcome
from replicate.grids.ray_executor import run_on_ray
from replicate.store import checkpoint_places
from replicate.store.runner import (
    DEFAULT_CHECKPOINT_INTERVAL,
    PreparedRun,
    check_device,
    execute,
    execute_batch,
    is_complete,
    load_run,
    prepare,
)
from replicate.store.spec import RunSpec

ORPHANED_EXIT_CODE = 3


_progress: Any = None  # a worker's end of the step-count queue, set when the worker starts
_device = "cpu"  # the worker's device, taken from the grid's list when the worker starts


# The command's time limit as a wall-clock deadline (time.time()), set for a whole command
# by ``time_limit``: every grid the command trains (a sweep trains several) stops there.
_deadline: float | None = None


@contextlib.contextmanager
def time_limit(deadline: float | None) -> Iterator[None]:
    """Within this block every ``run_grid`` stops at ``deadline`` (None: no limit): runs
    that finished are kept, running ones checkpoint at their next chance and stop, the
    others do not start, and ``TimeLimitStop`` says so."""
    global _deadline
    before, _deadline = _deadline, deadline
    try:
        yield
    finally:
        _deadline = before


def _init_worker(progress: Any, devices: Any, parent: int) -> None:
    global _progress, _device
    _progress = progress
    _device = devices.get()
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()


def _exit_with_parent(parent: int) -> None:
    """Once the figure's process is gone (killed), exit as a kill would, leaving the last
    checkpoint for the next invocation: neither training on unseen and unowned nor idling
    forever on a queue nobody feeds."""
    while os.getppid() == parent:
        time.sleep(1.0)
    os._exit(ORPHANED_EXIT_CODE)


def _worker(
    task: PreparedRun | list[PreparedRun],
    store: str,
    checkpoint_interval: int,
    follow_checkpoint: bool,
    env_workers: int = 0,
    deadline: float | None = None,
) -> list[tuple[str, str]]:
    """Train one run, or one batch of runs, in a worker process, posting step counts to the
    progress queue; return the (run id, reason) of batch members that failed alone. Past
    ``deadline`` a task does not start, and a running one checkpoints and stops
    (``TimeLimitReached``)."""
    if past(deadline):
        raise TimeLimitReached(None)
    progress = _progress
    pending = 0

    def on_steps(n: int) -> None:
        nonlocal pending
        pending += n
        if pending >= 250:
            progress.put(pending)
            pending = 0

    failed: list[tuple[str, str]] = []
    if isinstance(task, list):
        try:
            failed = execute_batch(
                task,
                Path(store),
                on_steps=on_steps,
                checkpoint_interval=checkpoint_interval,
                device=_device,
                follow_checkpoint=follow_checkpoint,
                env_workers=env_workers,
                deadline=deadline,
            ).failed
        finally:
            progress.put(pending)
    else:
        try:
            execute(
                task,
                Path(store),
                on_steps=on_steps,
                checkpoint_interval=checkpoint_interval,
                device=_device,
                follow_checkpoint=follow_checkpoint,
                deadline=deadline,
            )
        finally:
            progress.put(pending)
    return failed


EXECUTORS = ("local", "ray")


@dataclass(frozen=True)
class GridOptions:
    """How a grid trains: where, how many at once, how often it checkpoints, whether it only
    prints its plan. A figure passes it to ``run_grid`` unread; the command line fills it
    from the grid options every figure command shares (``cli_options.add_grid_arguments``)."""

    workers: int | None = None
    checkpoint_interval: int = DEFAULT_CHECKPOINT_INTERVAL
    executor: str = "local"
    address: str | None = None
    device: str = "auto"
    gpu_workers: int | None = None
    batch: int | None = None
    env_workers: int | None = None
    dry_run: bool = False
    deadline: float | None = None


def run_grid(
    specs: list[RunSpec], store: Path, options: GridOptions = GridOptions()
) -> GridOutcome:
    """Train every spec missing from the store with one progress display: in local
    processes (one per core by default), or as tasks on an existing Ray cluster.
    ``device``: ``auto`` (the GPU when there is one), ``cpu`` or ``cuda``, for the
    algorithms with a GPU path; the others always train on CPU. ``gpu_workers`` (with
    ``auto``) keeps only that many local workers on the GPU: see ``worker_devices``. On Ray,
    ``auto`` trains on CPUs; ``cuda`` is refused there.

    ``batch``: runs that differ only in seed train together, up to this many per process
    (``baselines.offpolicy``); on a GPU they do by default, as many as fit. ``env_workers``:
    processes stepping each batch's envs (default: the cores left over by the workers).

    ``deadline`` (a ``time.time()``; default: the one ``time_limit`` set): finished runs are
    kept, running ones checkpoint and stop, the rest do not start, and ``TimeLimitStop``
    is raised with the counts once the workers are done."""
    workers, device, batch, executor = (
        options.workers,
        options.device,
        options.batch,
        options.executor,
    )
    gpu_workers = options.gpu_workers
    deadline = _deadline if options.deadline is None else options.deadline
    if executor not in EXECUTORS:
        raise HarnessError(f"unknown executor '{executor}'", "pass --executor local or ray")
    if executor == "local":
        check_device(device)
    store = Path(store)
    prepared = [prepare(spec) for spec in specs]  # all input errors surface before training
    missing = [p for p in prepared if not is_complete(p.directory(store))]
    if executor == "ray":
        # Ray places one run per CPU and hands its tasks no GPU unless asked; all of a
        # node's runs on its GPU would also queue there (bench_gpu.json): CPUs it is
        if device == "cuda":
            raise HarnessError(
                "--device cuda is not supported with --executor ray",
                "pass --device auto (the cluster's CPUs), or train locally",
            )
        if batch is not None:
            raise HarnessError(
                "--batch is not supported with --executor ray", "drop --batch, or train locally"
            )
    if options.dry_run:
        resolve_batch(batch, missing, "cpu")  # its input checks, without touching a GPU
        print_plan(
            prepared,
            missing,
            store,
            workers or os.cpu_count() or 1,
            "local" if executor == "local" else "the Ray cluster's",
            batch,
            on_gpu=executor == "local" and gpu_requested(device, missing, gpu_workers),
        )
        return GridOutcome([], [], None)
    if executor == "ray":
        return _outcome(
            prepared,
            missing,
            store,
            *run_on_ray(
                prepared,
                missing,
                store,
                options.address,
                options.checkpoint_interval,
                "cpu",
                deadline,
            ),
        )
    grid = LocalGrid(prepared, missing, store, options, deadline)
    grid.plan()
    grid.train()
    return _outcome(
        prepared, missing, store, grid.started, grid.failed, grid.stopped, grid.not_started
    )


class LocalGrid:
    """A grid's missing runs trained in local worker processes, in named steps: ``plan`` the
    seed batches, the workers and their devices (and say so), then ``train`` them with one
    progress bar, ``settle`` each task as it ends (landed, failed alone, checkpointed at the
    time limit, or never started) and ``drain`` the workers' step counts into the bar."""

    def __init__(
        self,
        prepared: list[PreparedRun],
        missing: list[PreparedRun],
        store: Path,
        options: GridOptions,
        deadline: float | None,
    ):
        self.prepared, self.missing, self.store = prepared, missing, store
        self.options, self.deadline = options, deadline
        self.tasks: list[PreparedRun | list[PreparedRun]] = []
        self.devices: list[str] = []
        self.workers, self.env_workers = 1, 0
        self.started = time.time()
        self.failed: list[tuple[str, str]] = []
        self.stopped: list[str] = []  # checkpointed at the time limit
        self.not_started: list[str] = []
        self.done = 0

    def plan(self) -> None:
        options, missing, store = self.options, self.missing, self.store
        cores = os.cpu_count() or 1
        try:  # at most this many batches share the GPU at once
            slots = worker_devices(options.device, options.workers or cores, options.gpu_workers)
        except ValueError as exc:
            raise HarnessError(str(exc), "pass --gpu-workers 0 or more") from None
        checkpoint_places.tidy(store)  # what landed by another way is kept no more
        batch = resolve_batch(options.batch, missing, options.device, slots.count("cuda"))
        self.tasks = plan_batches(missing, batch, store)
        self.workers = max(1, min(options.workers or cores, max(1, len(self.tasks))))
        self.env_workers = (
            max(0, cores // self.workers - 1)
            if options.env_workers is None
            else options.env_workers
        )
        try:
            self.devices = worker_devices(options.device, self.workers, options.gpu_workers)
        except ValueError as exc:
            raise HarnessError(str(exc), "pass --gpu-workers 0 or more") from None
        on_gpu = self.devices.count("cuda")
        batches = [t for t in self.tasks if isinstance(t, list)]
        batched_note = (
            f" ({sum(len(b) for b in batches)} runs in {len(batches)} seed batches)"
            if batches
            else ""
        )
        ids = {p.run_id for p in missing}
        carried = sum(checkpoint_places.resumable_steps(store, ids).values())
        carried_note = f" ({carried:,} of them carried)" if carried else ""
        minutes = estimate_minutes(self.tasks, store, self.workers, on_gpu=on_gpu > 0)
        print(
            f"{len(self.prepared)} runs, {len(self.prepared) - len(missing)} already in {store}; "
            f"training {len(missing)} runs{batched_note}, {self.total_steps:,} env steps"
            f"{carried_note} on {self.workers} worker(s)"
            f"{f' ({on_gpu} on the GPU)' if on_gpu else ''}; "
            f"estimated {minutes:.0f} min on this machine (from the speeds of the store's runs)",
            flush=True,
        )

    @property
    def total_steps(self) -> int:
        return sum(p.spec.total_steps for p in self.missing)

    def train(self) -> None:
        self.started = time.time()
        if self.tasks and past(self.deadline):  # the limit passed while the grid was prepared
            ids = [p.run_id for p in self.missing]
            raise TimeLimitStop(_stop_summary(self.missing, self.store, [], ids, []))
        if not self.tasks:
            return
        ctx = mp.get_context("spawn")  # a clean interpreter per worker: no inherited torch state
        # a plain queue handed over at worker start: no manager process to outlive a kill
        progress = ctx.Queue()
        device_slots = ctx.Queue()
        for worker_device in self.devices:
            device_slots.put(worker_device)
        with tqdm(
            total=self.total_steps,
            unit="step",
            dynamic_ncols=True,
            mininterval=1.0,
            desc="training",
        ) as bar:
            with ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=ctx,
                initializer=_init_worker,
                initargs=(progress, device_slots, os.getpid()),
            ) as pool:
                futures = {self._submit(pool, task): task for task in self.tasks}
                pending = set(futures)
                while pending:
                    if past(self.deadline):  # what has not started yet never will
                        for future in pending:
                            future.cancel()
                    finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                    for future in finished:
                        self.settle(future, futures[future])
                    self.drain(progress, bar, wait_s=0.0)
                    bar.set_postfix_str(
                        f"runs done {self.done}/{len(self.missing)}, "
                        f"running {min(self.workers, len(pending))} task(s), "
                        f"failed {len(self.failed)}",
                        refresh=False,
                    )
            self.drain(progress, bar, wait_s=0.1)  # what the last workers posted at their end

    def _submit(self, pool: ProcessPoolExecutor, task: PreparedRun | list[PreparedRun]) -> Future:
        return pool.submit(
            _worker,
            task,
            str(self.store),
            self.options.checkpoint_interval,
            self.options.device == "auto",
            self.env_workers,
            self.deadline,
        )

    def settle(self, future: Future, task: PreparedRun | list[PreparedRun]) -> None:
        """Record how one task ended."""
        error = None if future.cancelled() else future.exception()
        if future.cancelled() or (isinstance(error, TimeLimitReached) and error.step is None):
            self.not_started.extend(task_ids(task))
            return
        if isinstance(error, TimeLimitReached):
            self.stopped.extend(task_ids(task))
            return
        self.done += len(task_ids(task))
        if error is not None:
            reason = f"{type(error).__name__}: {error}".replace("\n", " ")
            lost = [(run_id, reason) for run_id in task_ids(task)]
        else:
            lost = future.result()
        for run_id, reason in lost:
            self.failed.append((run_id, reason))
            tqdm.write(f"run failed: {run_id}: {reason}")

    @staticmethod
    def drain(progress: Any, bar: tqdm, wait_s: float) -> None:
        """The step counts the workers posted, into the bar (waiting ``wait_s`` for each)."""
        try:
            while True:
                bar.update(progress.get(timeout=wait_s) if wait_s else progress.get_nowait())
        except queue.Empty:
            pass


def _outcome(
    prepared: list[PreparedRun],
    missing: list[PreparedRun],
    store: Path,
    started: float,
    failed: list[tuple[str, str]],
    stopped: list[str],
    not_started: list[str],
) -> GridOutcome:
    """A trained grid's outcome: its complete runs, those that failed and the time since
    ``started``; ``TimeLimitStop`` instead where runs stopped at the time limit or never
    started."""
    runs = [load_run(p.directory(store)) for p in prepared if is_complete(p.directory(store))]
    if stopped or not_started:
        raise TimeLimitStop(_stop_summary(missing, store, stopped, not_started, failed))
    return GridOutcome(runs, failed, time.time() - started)


def _stop_summary(
    missing: list[PreparedRun],
    store: Path,
    stopped: list[str],
    not_started: list[str],
    failed: list[tuple[str, str]],
) -> str:
    """What a grid stopped at its time limit leaves: runs kept, checkpointed, not started."""
    landed = sum(is_complete(p.directory(store)) for p in missing)
    parts = [
        f"{landed} of {len(missing)} runs finished and kept",
        f"{len(stopped)} checkpointed at the limit",
        f"{len(not_started)} not started",
    ]
    if failed:
        parts.append(f"{len(failed)} failed")
    return ", ".join(parts)
