"""Experiment specs: a figure is a grid of runs (data) plus a way to draw and judge them.

Profiles set the budgets: ``smoke`` proves the pipeline in seconds and means nothing;
``quick`` is a real, reduced replication for a 2-core machine; ``paper`` uses the paper's
budgets and is meant for a cluster or a GPU machine.
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing as mp
import os
import queue
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any, Callable, Iterator

from tqdm import tqdm

from baselines.common.checkpoint import TimeLimitReached, past
from baselines.common.device import worker_devices
from replicate import carry
from replicate.drl_eg_settings import (  # noqa: F401  (used here, and the grids' callers)
    ALWAYS_GUIDE,
    DEFAULT_GUIDE_NOISE_STD,
    DRL_EG_ENV_DEFAULTS,
    MUJOCO_ENVS,
    RULED_PROFILES,
    SPACING_MULTIPLES,
    T2_ALGORITHMS,
    T2_RULE_SETTINGS,
    T2_WAIT_REASON,
    drl_eg_env_defaults,
    guidance_settings,
    t2_source,
    takes_t2_rule,
    waits_for_t2_rule,
)
from replicate.errors import HarnessError, TimeLimitStop
from replicate.profiles import (  # noqa: F401
    BUDGETS,
    PAPER_BUDGETS,
    PAPER_SEEDS_FIG3,
    PROFILES,
    GridOutcome,
    Profile,
    get_profile,
    report_dir,
)
from replicate.provenance import portable_path
from replicate.runner import (
    DEFAULT_CHECKPOINT_INTERVAL,
    PreparedRun,
    Run,
    batch_key,
    check_device,
    execute,
    execute_batch,
    is_complete,
    load_run,
    prepare,
)
from replicate.spec import RunSpec
from replicate.store import completed_runs


def algorithm_overrides(algo: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The profile's overrides that ``algo``'s config has (each takes what it knows)."""
    from baselines.registry import get_algorithm

    known = {f.name for f in dataclasses.fields(get_algorithm(algo).config_cls)}
    return {k: v for k, v in overrides.items() if k in known}


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


def _init_worker(progress: Any, devices: Any) -> None:
    global _progress, _device
    _progress = progress
    _device = devices.get()


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
    parent = os.getppid()

    def on_steps(n: int) -> None:
        nonlocal pending
        if os.getppid() != parent:
            # The figure's process is gone (killed): stop as a kill would, leaving the last
            # checkpoint for the next invocation, instead of training on unseen and unowned.
            os._exit(ORPHANED_EXIT_CODE)
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


def carried_tasks(
    missing: list[PreparedRun], store: Path | None
) -> tuple[list[PreparedRun | list[PreparedRun]], list[PreparedRun]]:
    """The runs and seed batches carried in the store (``replicate.carry``) whose members
    are all missing, each as it was carried (a batch as the batch it was, a run alone), and
    the missing runs left over."""
    if store is None:
        return [], list(missing)
    by_id = {p.run_id: p for p in missing}
    tasks: list[PreparedRun | list[PreparedRun]] = []
    for manifest in carry.listing(store):
        if all(r in by_id for r in manifest["members"]):
            members = [by_id.pop(r) for r in manifest["members"]]
            tasks.append(members if len(members) > 1 else members[0])
    return tasks, [p for p in missing if p.run_id in by_id]


def plan_batches(
    missing: list[PreparedRun], batch: int | None, store: Path | None = None
) -> list[PreparedRun | list[PreparedRun]]:
    """The grid's tasks: runs of an algorithm with a batched trainer grouped, at most
    ``batch`` per group, by everything but their seed; every other run alone. ``batch``
    None or 1: every run alone. What is carried in ``store`` resumes as it was carried,
    whatever ``batch`` says."""
    from baselines.registry import batched_trainer

    carried, missing = carried_tasks(missing, store)
    if batch is None or batch <= 1:
        return [*carried, *missing]
    groups: dict[str, list[PreparedRun]] = {}
    tasks = [t for t in carried if not isinstance(t, list)]
    for p in missing:
        if batched_trainer(p.spec.algo) is None:
            tasks.append(p)
        else:
            groups.setdefault(batch_key(p), []).append(p)
    batches = [t for t in carried if isinstance(t, list)]
    batches += [
        group[i : i + batch] for group in groups.values() for i in range(0, len(group), batch)
    ]
    # the longest work first, so that the one-run tasks fill the gaps
    return sorted(batches, key=lambda b: -sum(p.spec.total_steps for p in b)) + tasks


def _task_steps(task: PreparedRun | list[PreparedRun]) -> int:
    members = task if isinstance(task, list) else [task]
    return sum(p.spec.total_steps for p in members)


def _task_ids(task: PreparedRun | list[PreparedRun]) -> list[str]:
    return [p.run_id for p in task] if isinstance(task, list) else [task.run_id]


DEFAULT_STEPS_PER_S = 40.0  # a guess for an algorithm the store has never timed


def measured_rates(store: Path, on_gpu: bool = False) -> dict[tuple[str, str], float]:
    """Env steps per second of the process that trained each of the store's finished runs
    (a seed batch's members' steps summed), averaged by (algorithm, env): of the runs trained
    on CPU, or with ``on_gpu`` of those trained on a GPU where an (algorithm, env) has any,
    else on CPU (a GPU batch steps several times faster than a CPU process, so a CPU plan
    never takes a GPU's speed)."""
    rates: dict[tuple[bool, str, str], list[float]] = {}
    for run in completed_runs(store):
        if run.process_rate is not None:
            key = (run.trained_on_gpu, run.spec["algo"], run.spec["env_id"])
            rates.setdefault(key, []).append(run.process_rate)
    means = {key: sum(values) / len(values) for key, values in rates.items()}
    chosen = {(algo, env_id): rate for (gpu, algo, env_id), rate in means.items() if not gpu}
    if on_gpu:
        chosen.update({(algo, env_id): rate for (gpu, algo, env_id), rate in means.items() if gpu})
    return chosen


def estimate_minutes(
    tasks: list[PreparedRun | list[PreparedRun]],
    store: Path,
    workers: int,
    rates: dict[tuple[str, str], float] | None = None,
    on_gpu: bool = False,
    carried_batches: bool = True,
) -> float:
    """Wall minutes to train ``tasks`` (runs, or seed batches that train their members at
    once) on ``workers`` processes, from the speed each algorithm had on each env in the
    store (else the same algorithm's slowest env, else the env's slowest algorithm, else a
    guess; ``rates``: ``measured_rates(store, on_gpu)`` read already), less the steps that
    runs carried in ``store`` resume from (of carried runs only with ``carried_batches``
    False: an executor of one run per task starts a carried batch over). A process is taken
    to step as fast whatever its batch's size: about so on CPU, where the products
    dominate; a GPU batch steps faster the larger it is, so rates from large GPU batches
    make smaller batches and single runs look faster than they are."""
    rates = measured_rates(store, on_gpu) if rates is None else rates
    # a carried run resumes at its carried step: only the rest is trained here
    done = carry.resumable_steps(
        store, {r for task in tasks for r in _task_ids(task)}, batches=carried_batches
    )
    by_algo: dict[str, list[float]] = {}
    by_env: dict[str, list[float]] = {}
    for (algo, env_id), rate in rates.items():
        by_algo.setdefault(algo, []).append(rate)
        by_env.setdefault(env_id, []).append(rate)
    seconds = 0.0
    for task in tasks:
        members = task if isinstance(task, list) else [task]
        p = members[0]
        # untimed here: the algorithm's slowest other env; a new algorithm costs most like
        # the env's slowest timed one (the env's step and network sizes dominate; slow errs
        # on the safe side)
        rate = rates.get((p.spec.algo, p.spec.env_id)) or min(
            by_algo.get(p.spec.algo) or by_env.get(p.spec.env_id) or [DEFAULT_STEPS_PER_S]
        )
        seconds += sum(m.spec.total_steps - done.get(m.run_id, 0) for m in members) / rate
    return seconds / workers / 60


EXECUTORS = ("local", "ray")


DEFAULT_GPU_BATCH = 64  # members per batch on a GPU when --batch is not given


def _gpu_requested(device: str, missing: list[PreparedRun], gpu_workers: int | None) -> bool:
    """Whether ``device`` (``cuda`` checked already) puts some of ``missing`` on a GPU:
    one of them has a GPU path and ``gpu_workers`` leaves a worker on the GPU."""
    from baselines.common.device import resolve_device
    from baselines.registry import get_algorithm

    return gpu_workers != 0 and any(
        resolve_device(device, get_algorithm(p.spec.algo).gpu) == "cuda" for p in missing
    )


def resolve_batch(
    batch: int | None, missing: list[PreparedRun], device: str, concurrent: int = 1
) -> int | None:
    """The batch size a grid trains with: ``batch`` if given (checked), else on a GPU the
    largest up to ``DEFAULT_GPU_BATCH`` such that ``concurrent`` batches at once fit its
    memory, else None (one run per process). Bad sizes raise a one-line
    :class:`HarnessError`."""
    from baselines.common.device import resolve_device
    from baselines.registry import batchable_algorithms, batched_trainer

    if batch is not None and batch < 1:
        raise HarnessError(f"batch size must be >= 1, got {batch}", "pass --batch 4, say")
    batchable = [p for p in missing if batched_trainer(p.spec.algo) is not None]
    if batch is not None and batch > 1 and missing and not batchable:
        names = sorted({p.spec.algo for p in missing})
        raise HarnessError(
            f"--batch {batch}: no batched trainer for {', '.join(names)}",
            f"drop --batch (or batch {', '.join(batchable_algorithms())} runs)",
        )
    on_gpu = resolve_device(device, has_gpu_path=True) == "cuda"
    if not on_gpu or not batchable:
        return batch
    import torch

    free, _ = torch.cuda.mem_get_info()
    need = max(batch_bytes(p, 1) for p in batchable) * max(1, concurrent)
    fits = int(0.8 * free // need)
    if batch is None:
        return max(1, min(DEFAULT_GPU_BATCH, fits))
    if batch > fits:
        raise HarnessError(
            f"{max(1, concurrent)} batch(es) of {batch} at once need about "
            f"{batch * need / 2**30:.1f} GiB of GPU memory; "
            f"{free / 2**30:.1f} GiB are free",
            f"pass --batch {max(1, fits)} or less, or fewer --workers",
        )
    return batch


def batch_bytes(prepared: PreparedRun, members: int) -> int:
    """Device memory of ``members`` runs like ``prepared`` in one batch: their replay, plus
    their networks, optimiser state and activations (a generous 64 MiB each per pair of
    critics: RLPD's ten count five times)."""
    from baselines.common.stacked import StackedReplay
    from envs import env_spec

    env = env_spec(prepared.spec.env_id)
    capacity = min(prepared.config.buffer_size, prepared.spec.total_steps)
    replay = StackedReplay.bytes_per_member(env.obs_dim, env.act_dim, capacity)
    critic_pairs = max(1, getattr(prepared.config, "num_qs", 2) // 2)
    return members * (replay + critic_pairs * 2**26)


def print_plan(
    prepared: list[PreparedRun],
    missing: list[PreparedRun],
    store: Path,
    workers: int,
    where: str = "local",
    batch: int | None = None,
    on_gpu: bool = False,
) -> None:
    """What a grid would train: its missing runs per env and algorithm, their env steps,
    and the minutes they would take (from the speeds the store's runs recorded), per cell in
    one process and in all on up to ``workers`` ``where`` workers, one run per process or,
    with ``batch``, in the seed batches ``plan_batches`` makes; ``on_gpu``: from the speeds
    of runs trained on a GPU where there are any, and without ``batch`` in batches of
    ``DEFAULT_GPU_BATCH`` (a GPU grid's batches are as large as its memory allows)."""
    groups: dict[tuple[str, str], list[PreparedRun]] = {}
    for p in missing:
        groups.setdefault((p.spec.env_id, p.spec.algo), []).append(p)
    # a sweep's points are cells of their own, named by the settings that tell them apart
    cells: dict[tuple[str, str, str], list[PreparedRun]] = {}
    for (env_id, algo), runs in groups.items():
        keys = set().union(*(p.spec.hyperparameters for p in runs))
        varying = sorted(
            k for k in keys if len({repr(p.spec.hyperparameters.get(k)) for p in runs}) > 1
        )
        for p in runs:
            settings = " ".join(f"{k}={p.spec.hyperparameters.get(k, 'default')}" for k in varying)
            cells.setdefault((env_id, algo, settings), []).append(p)
    print(
        f"dry run: {len(prepared)} runs, {len(prepared) - len(missing)} already in {store}, "
        f"{len(missing)} to train; nothing is trained or written"
    )
    rates = measured_rates(store, on_gpu)
    for (env_id, algo, settings), runs in sorted(cells.items()):
        seeds = ",".join(str(p.spec.seed) for p in sorted(runs, key=lambda p: p.spec.seed))
        steps = sum(p.spec.total_steps for p in runs)
        carried = sum(carry.resumable_steps(store, {p.run_id for p in runs}).values())
        point = f"  ({settings})" if settings else ""
        point += f"  ({carried:,} of them carried)" if carried else ""
        print(
            f"  {env_id:<40} {algo:<14} seeds {seeds:<14} {steps:>12,} env steps  "
            f"~{estimate_minutes(runs, store, 1, rates):,.0f} min in one process{point}"
        )
    total = sum(p.spec.total_steps for p in missing)
    if where != "local":  # the cluster's size is not known without connecting to it
        print(
            f"  total {total:,} env steps: about "
            f"{estimate_minutes(missing, store, 1, rates, carried_batches=False):,.0f} "
            "process-minutes on "
            f"{where} CPUs"
        )
        return
    tasks = plan_batches(missing, DEFAULT_GPU_BATCH if on_gpu and batch is None else batch, store)
    asked = {p.run_id for p in missing}
    for manifest in carry.listing(store):
        members = set(manifest["members"])
        if not asked & members:
            continue
        where = (
            f"carried: {manifest['kind']} {manifest['name']} at step {manifest['step']:,} "
            f"(packed {manifest['packed_utc']} on {manifest['cpu_model']})"
        )
        if members <= asked:
            print(
                f"  {where}; it resumes from there"
                + (" as the batch it was" if len(members) > 1 else "")
            )
        else:
            print(
                f"  {where}: {len(members - asked)} of its runs are not in this plan, so "
                "it does not resume here; its runs in the plan start over"
            )
    carried = sum(carry.resumable_steps(store, {p.run_id for p in missing}).values())
    batches = [t for t in tasks if isinstance(t, list)]
    used = max(1, min(workers, len(tasks)))
    longest = max((estimate_minutes([t], store, 1, rates) for t in tasks), default=0.0)
    minutes = max(estimate_minutes(tasks, store, used, rates), longest)
    how = "one run per process"
    if batches:
        alone, batched = len(tasks) - len(batches), sum(len(b) for b in batches)
        how = (
            f"{batched} run{'s' if batched > 1 else ''} in {len(batches)} seed "
            f"batch{'es' if len(batches) > 1 else ''}"
            + (f", {alone} run{'s' if alone > 1 else ''} one per process" if alone else "")
        )
    print(
        f"  total {total:,} env steps"
        + (f" ({total - carried:,} to train, the rest carried)" if carried else "")
        + f": about {minutes:,.0f} min on {used} local worker(s), {how}"
    )


def run_grid(
    specs: list[RunSpec],
    store: Path,
    workers: int | None = None,
    checkpoint_interval: int = DEFAULT_CHECKPOINT_INTERVAL,
    executor: str = "local",
    address: str | None = None,
    device: str = "auto",
    gpu_workers: int | None = None,
    batch: int | None = None,
    env_workers: int | None = None,
    dry_run: bool = False,
    deadline: float | None = None,
) -> GridOutcome:
    """Train every spec missing from the store with one progress display: in local
    processes (one per core by default), or as tasks on an existing Ray cluster.
    ``device``: ``auto`` (the GPU when there is one), ``cpu`` or ``cuda``, for the algorithms
    with a GPU path; the others always train on CPU. ``gpu_workers`` (with ``auto``) keeps
    only that many local workers on the GPU: see ``worker_devices``. On Ray, ``auto`` trains
    on CPUs; ``cuda`` is refused there.

    ``batch``: runs that differ only in seed train together, up to this many per process
    (``baselines.offpolicy``); on a GPU they do by default, as many as fit. ``env_workers``:
    processes stepping each batch's envs (default: the cores left over by the workers).

    ``deadline`` (a ``time.time()``; default: the one ``time_limit`` set): finished runs are
    kept, running ones checkpoint and stop, the rest do not start, and ``TimeLimitStop``
    is raised with the counts once the workers are done."""
    deadline = _deadline if deadline is None else deadline
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
    if dry_run:
        resolve_batch(batch, missing, "cpu")  # its input checks, without touching a GPU
        print_plan(
            prepared,
            missing,
            store,
            workers or os.cpu_count() or 1,
            "local" if executor == "local" else "the Ray cluster's",
            batch,
            on_gpu=executor == "local" and _gpu_requested(device, missing, gpu_workers),
        )
        return GridOutcome([], [], None)
    if executor == "ray":
        return _run_on_ray(prepared, missing, store, address, checkpoint_interval, "cpu", deadline)
    try:  # at most this many batches share the GPU at once
        gpu_slots = worker_devices(device, workers or os.cpu_count() or 1, gpu_workers).count(
            "cuda"
        )
    except ValueError as exc:
        raise HarnessError(str(exc), "pass --gpu-workers 0 or more") from None
    carry.prune(store)  # what landed elsewhere is carried no more
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
    carried = sum(carry.resumable_steps(store, {p.run_id for p in missing}).values())
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
                initargs=(progress, device_slots),
            ) as pool:
                futures: dict[Future, PreparedRun | list[PreparedRun]] = {
                    pool.submit(
                        _worker,
                        task,
                        str(store),
                        checkpoint_interval,
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
                            not_started.extend(_task_ids(task))
                            continue
                        if isinstance(error, TimeLimitReached):
                            stopped.extend(_task_ids(task))
                            continue
                        done_count += len(_task_ids(task))
                        if error is not None:
                            reason = f"{type(error).__name__}: {error}".replace("\n", " ")
                            lost = [(run_id, reason) for run_id in _task_ids(task)]
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


def without_waiting(
    specs: list[RunSpec], skipped: list[tuple[str, str, str]], profile: str
) -> tuple[list[RunSpec], list[tuple[str, str, str]]]:
    """A grid less its cells that wait for the MuJoCo T2 rule, those listed as skipped: a
    report never shows them, even where the store holds runs of the same spec (the
    ablation's 1x point is one)."""
    waiting = [s for s in specs if waits_for_t2_rule(profile, s.env_id, s.algo)]
    return (
        [s for s in specs if s not in waiting],
        skipped + sorted({(s.env_id, s.algo, T2_WAIT_REASON) for s in waiting}),
    )


def train_and_report(
    specs: list[RunSpec],
    skipped: list[tuple[str, str, str]],
    profile: str,
    command: str,
    store: Path,
    out_dir: Path,
    write: Callable[[GridOutcome, Path], Path],
    algos: list[str] | None = None,
    envs: list[str] | None = None,
    dry_run: bool = False,
    **grid_options: Any,
) -> Path | None:
    """A figure command: train what its grid lacks (of the ``algos`` x ``envs`` cells when
    given; cells that wait for the MuJoCo T2 rule never), then ``write(outcome, out_dir)``
    its report from every run of the grid in the store, never over a report that names more
    runs (``report.write_unless_fewer``). Returns the report (None: nothing written)."""
    selected = select_cells(specs, algos, envs)
    specs, skipped = without_waiting(specs, skipped, profile)
    chosen = [s for s in selected if s in specs]
    if (algos or envs) and not chosen:
        why = "; they wait for the MuJoCo T2 rule" if selected else ""
        raise HarnessError(
            f"--algos/--envs: no cell of this grid to train there{why}",
            "choose other cells (`--dry-run` lists what is missing)",
        )
    for env_id, algo, reason in skipped:  # the report lists them all; here the chosen ones
        if (algos is None or algo in algos) and (envs is None or env_id in envs):
            print(f"skipped {algo} on {env_id}: {reason}")
    outcome = train_cells(specs, chosen, store, command, dry_run=dry_run, **grid_options)
    if dry_run:
        return None
    outcome.skipped = skipped + outcome.skipped
    report = write_saying_why(Path(out_dir), Path(store), lambda out: write(outcome, out))
    if outcome.failed:
        where = (
            f"the report at {report} lists them"
            if report is not None
            else f"e.g. {outcome.failed[0][0]}: {outcome.failed[0][1]}"
        )
        raise HarnessError(
            f"{len(outcome.failed)} run(s) failed; {where}",
            "read the reasons, fix, and run the same command",
        )
    return report


def write_saying_why(
    out_dir: Path, store: Path, build: Callable[[Path], Path | None]
) -> Path | None:
    """``report.write_unless_fewer``, printing its line when some of the old report's runs
    were missing; returns the index written (None: nothing written)."""
    from replicate.report import write_unless_fewer

    report, note = write_unless_fewer(out_dir, store, build)
    if note:
        print(note if report is None else f"{out_dir}: {note}")
    return report


def stored_runs(specs: list[RunSpec], store: Path) -> list[Run]:
    """The complete runs of ``specs`` in the store (nothing is trained)."""
    return stored_and_absent(specs, store)[0]


def stored_and_absent(specs: list[RunSpec], store: Path) -> tuple[list[Run], list[RunSpec]]:
    """The complete runs of ``specs`` in the store (in the order of ``specs``), and the specs
    whose run is not there yet."""
    runs, absent = [], []
    for spec in specs:
        directory = prepare(spec).directory(store)
        if is_complete(directory):
            runs.append(load_run(directory))
        else:
            absent.append(spec)
    return runs, absent


def absent_cells(
    specs: list[RunSpec], command: str, store: Path | None = None
) -> list[tuple[str, str, str]]:
    """A report's (env, algo, reason) line per cell for the runs not in the store yet, with
    the seeds each cell lacks and, for those carried unfinished in ``store``
    (``replicate.carry``), the step they are carried at."""
    carried_at = {
        run_id: manifest["step"]
        for manifest in (carry.listing(store) if store is not None else [])
        for run_id in manifest["members"]
    }
    seeds: dict[tuple[str, str], list[int]] = {}
    steps: dict[tuple[str, str], list[tuple[int, int]]] = {}
    for spec in specs:
        cell = (spec.env_id, spec.algo)
        seeds.setdefault(cell, []).append(spec.seed)
        step = carried_at.get(prepare(spec).run_id) if carried_at else None
        if step is not None:
            steps.setdefault(cell, []).append((spec.seed, step))
    lines = []
    for cell, lacking in seeds.items():
        one = len(lacking) == 1
        carried_note = ""
        if cell in steps:
            at = ", ".join(f"seed {seed} at step {step:,}" for seed, step in sorted(steps[cell]))
            where = portable_path(carry.carry_root(store))
            carried_note = f"; carried unfinished in {where}: {at}"
        lines.append(
            (
                *cell,
                f"{'seed' if one else 'seeds'} {', '.join(map(str, sorted(lacking)))} "
                f"not in the store yet{carried_note} (run `{command}` to "
                f"{'train' if not carried_note else 'train or resume'} "
                f"{'it' if one else 'them'})",
            )
        )
    return lines


def stored_outcome(
    specs: list[RunSpec],
    skipped: list[tuple[str, str, str]],
    profile: str,
    store: Path,
    command: str,
) -> GridOutcome | None:
    """A grid's outcome from the store alone, for a rebuilt report: its complete runs, the
    cells that wait for the T2 rule and the runs not there yet listed as skipped; None when
    the store holds none of its runs."""
    specs, skipped = without_waiting(specs, skipped, profile)
    runs, absent = stored_and_absent(specs, store)
    if not runs:
        return None
    return GridOutcome(runs, [], None, skipped + absent_cells(absent, command, store))


def select_cells(
    specs: list[RunSpec], algos: list[str] | None, envs: list[str] | None
) -> list[RunSpec]:
    """The specs of a grid whose algorithm is in ``algos`` and env in ``envs`` (None: any);
    a name the grid does not have is a one-line error that lists the ones it has."""
    for chosen, field, flag in ((algos, "algo", "--algos"), (envs, "env_id", "--envs")):
        if chosen is None:
            continue
        have = sorted({getattr(s, field) for s in specs})
        unknown = [name for name in chosen if name not in have]
        if unknown:
            raise HarnessError(
                f"{flag}: {', '.join(unknown)} not in this grid", f"choose from {', '.join(have)}"
            )
    return [
        s
        for s in specs
        if (algos is None or s.algo in algos) and (envs is None or s.env_id in envs)
    ]


def train_cells(
    specs: list[RunSpec],
    chosen: list[RunSpec],
    store: Path,
    command: str,
    dry_run: bool = False,
    **grid_options: Any,
) -> GridOutcome:
    """Train the ``chosen`` part of a grid (what is missing of it); the outcome holds every
    complete run of the whole grid, and the cells outside ``chosen`` that are still absent
    are listed, so a report written from it covers the whole grid."""
    outcome = run_grid(chosen, store, dry_run=dry_run, **grid_options)
    if len(chosen) == len(specs) or dry_run:
        return outcome
    outcome.runs, absent = stored_and_absent(specs, store)  # in the grid's order
    outcome.skipped = absent_cells([spec for spec in absent if spec not in chosen], command, store)
    return outcome


def _ray_execute(
    prepared: PreparedRun,
    store: str,
    checkpoint_interval: int,
    device: str,
    deadline: float | None = None,
) -> str:
    if past(deadline):
        raise TimeLimitReached(None)
    execute(
        prepared,
        Path(store),
        checkpoint_interval=checkpoint_interval,
        device=device,
        deadline=deadline,
    )
    return prepared.run_id


def _run_on_ray(
    prepared: list[PreparedRun],
    missing: list[PreparedRun],
    store: Path,
    address: str | None,
    checkpoint_interval: int,
    device: str = "auto",
    deadline: float | None = None,
) -> GridOutcome:
    """One Ray task per missing run, one CPU each. The store must be a path every node
    sees (a shared filesystem), and every node needs this project installed."""
    try:
        import ray
    except ImportError:
        raise HarnessError("the Ray executor needs ray", "pip install 'ray>=2.9'") from None
    if address is None:
        raise HarnessError(
            "--executor ray needs the cluster's address",
            "pass --address HOST:PORT of a running Ray head",
        )
    ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
    cluster_cpus = int(ray.cluster_resources().get("CPU", 1))
    total_steps = sum(p.spec.total_steps for p in missing)
    print(
        f"{len(prepared)} runs, {len(prepared) - len(missing)} already in {store}; "
        f"training {len(missing)} runs, {total_steps:,} env steps on the Ray cluster at "
        f"{address} ({cluster_cpus} CPUs); estimated "
        f"{estimate_minutes(missing, store, cluster_cpus, carried_batches=False):.0f} min",
        flush=True,
    )
    asked = {p.run_id for p in missing}
    carried_batches = [
        m["name"]
        for m in carry.listing(store)
        if len(m["members"]) > 1 and asked & set(m["members"])
    ]
    if carried_batches:
        print(
            f"note: {', '.join(carried_batches)} (carried seed batches) resume with the "
            "local executor only; on Ray their runs start over",
            flush=True,
        )
    started = time.time()
    failed: list[tuple[str, str]] = []
    stopped: list[str] = []
    not_started: list[str] = []
    remote = ray.remote(num_cpus=1, max_retries=0)(_ray_execute)
    pending = {
        remote.remote(p, str(store.resolve()), checkpoint_interval, device, deadline): p
        for p in missing
    }
    with tqdm(total=len(missing), unit="run", dynamic_ncols=True, desc="training on Ray") as bar:
        while pending:
            finished, _ = ray.wait(list(pending), num_returns=1)
            for ref in finished:
                run = pending.pop(ref)
                try:
                    ray.get(ref)
                except Exception as error:  # the run's own error, wrapped by Ray
                    cause = getattr(error, "cause", None) or error
                    if isinstance(cause, TimeLimitReached):
                        (stopped if cause.step is not None else not_started).append(run.run_id)
                    else:
                        reason = f"{type(cause).__name__}: {cause}".replace("\n", " ")
                        failed.append((run.run_id, reason))
                        tqdm.write(f"run failed: {run.run_id}: {reason}")
                bar.update(1)
                bar.set_postfix_str(
                    f"running {min(len(pending), cluster_cpus)}, "
                    f"left {len(pending)}, failed {len(failed)}",
                    refresh=False,
                )
    runs = [load_run(p.directory(store)) for p in prepared if is_complete(p.directory(store))]
    if stopped or not_started:
        raise TimeLimitStop(_stop_summary(missing, store, stopped, not_started, failed))
    return GridOutcome(runs, failed, time.time() - started)
