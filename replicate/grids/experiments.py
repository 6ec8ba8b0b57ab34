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
    gpu_workers, env_workers = options.gpu_workers, options.env_workers
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
    try:  # at most this many batches share the GPU at once
        gpu_slots = worker_devices(device, workers or os.cpu_count() or 1, gpu_workers).count(
            "cuda"
        )
    except ValueError as exc:
        raise HarnessError(str(exc), "pass --gpu-workers 0 or more") from None
    checkpoint_places.tidy(store)  # what landed by another way is kept no more
    tasks = plan_batches(missing, resolve_batch(batch, missing, device, gpu_slots), store)
    workers = max(1, min(workers or os.cpu_count() or 1, max(1, len(tasks))))
    if env_workers is None:
        env_workers = max(0, (os.cpu_count() or 1) // workers - 1)
    try:
        devices = worker_devices(device, workers, gpu_workers)
    except ValueError as exc:
        raise HarnessError(str(exc), "pass --gpu-workers 0 or more") from None
    on_gpu = devices.count("cuda")
    total_steps = sum(p.spec.total_steps for p in missing)
    batches = [t for t in tasks if isinstance(t, list)]
    batched_note = (
        f" ({sum(len(b) for b in batches)} runs in {len(batches)} seed batches)" if batches else ""
    )
    carried = sum(checkpoint_places.resumable_steps(store, {p.run_id for p in missing}).values())
    carried_note = f" ({carried:,} of them carried)" if carried else ""
    print(
        f"{len(prepared)} runs, {len(prepared) - len(missing)} already in {store}; "
        f"training {len(missing)} runs{batched_note}, {total_steps:,} env steps{carried_note} on "
        f"{workers} worker(s){f' ({on_gpu} on the GPU)' if on_gpu else ''}; "
        f"estimated {estimate_minutes(tasks, store, workers, on_gpu=on_gpu > 0):.0f} min "
        "on this machine "
        "(from the speeds of the store's runs)",
        flush=True,
    )

    started = time.time()
    failed: list[tuple[str, str]] = []
    stopped: list[str] = []  # checkpointed at the time limit
    not_started: list[str] = []
    if tasks and past(deadline):  # the limit passed while the grid was prepared
        raise TimeLimitStop(_stop_summary(missing, store, [], [p.run_id for p in missing], []))
    if tasks:
        ctx = mp.get_context("spawn")  # a clean interpreter per worker: no inherited torch state
        # a plain queue handed over at worker start: no manager process to outlive a kill
        progress = ctx.Queue()
        device_slots = ctx.Queue()
        for worker_device in devices:
            device_slots.put(worker_device)
        with tqdm(
            total=total_steps, unit="step", dynamic_ncols=True, mininterval=1.0, desc="training"
        ) as bar:
            with ProcessPoolExecutor(
                max_workers=workers,
                mp_context=ctx,
                initializer=_init_worker,
                initargs=(progress, device_slots, os.getpid()),
            ) as pool:
                futures: dict[Future, PreparedRun | list[PreparedRun]] = {
                    pool.submit(
                        _worker,
                        task,
                        str(store),
                        options.checkpoint_interval,
                        device == "auto",
                        env_workers,
                        deadline,
                    ): task
                    for task in tasks
                }
                pending = set(futures)
                done_count = 0
                while pending:
                    if past(deadline):  # what has not started yet never will
                        for future in pending:
                            future.cancel()
                    finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                    for future in finished:
                        task = futures[future]
                        error = None if future.cancelled() else future.exception()
                        lost: list[tuple[str, str]] = []
                        if future.cancelled() or (
                            isinstance(error, TimeLimitReached) and error.step is None
                        ):
                            not_started.extend(task_ids(task))
                            continue
                        if isinstance(error, TimeLimitReached):
                            stopped.extend(task_ids(task))
                            continue
                        done_count += len(task_ids(task))
                        if error is not None:
                            reason = f"{type(error).__name__}: {error}".replace("\n", " ")
                            lost = [(run_id, reason) for run_id in task_ids(task)]
                        else:
                            lost = future.result()
                        for run_id, reason in lost:
                            failed.append((run_id, reason))
                            tqdm.write(f"run failed: {run_id}: {reason}")
                    try:
                        while True:
                            bar.update(progress.get_nowait())
                    except queue.Empty:
                        pass
                    bar.set_postfix_str(
                        f"runs done {done_count}/{len(missing)}, "
                        f"running {min(workers, len(pending))} task(s), "
                        f"failed {len(failed)}",
                        refresh=False,
                    )
            try:  # what the last workers posted as they finished
                while True:
                    bar.update(progress.get(timeout=0.1))
            except queue.Empty:
                pass
    return _outcome(prepared, missing, store, started, failed, stopped, not_started)


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
