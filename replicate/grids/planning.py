"""A grid's plan, before anything trains: its tasks (runs alone, and seed batches of runs
that differ only in seed), the minutes they would take from the speeds of the store's runs,
the batch size a GPU fits, and the dry run's listing of it all."""

from __future__ import annotations

from pathlib import Path

from replicate.errors import HarnessError
from replicate.store import checkpoint_places
from replicate.store.runner import PreparedRun, batch_key
from replicate.store.runs import completed_runs


def carried_tasks(
    missing: list[PreparedRun], store: Path | None
) -> tuple[list[PreparedRun | list[PreparedRun]], list[PreparedRun]]:
    """The runs and seed batches whose checkpoints are kept elsewhere for the store
    (``replicate.store.checkpoint_places``: carried, say) and whose members are all missing, each
    as it was kept (a batch as the batch it was, a run alone), and the missing runs left
    over."""
    if store is None:
        return [], list(missing)
    by_id = {p.run_id: p for p in missing}
    tasks: list[PreparedRun | list[PreparedRun]] = []
    for kept in checkpoint_places.kept(store):
        if all(r in by_id for r in kept.members):
            members = [by_id.pop(r) for r in kept.members]
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


def task_ids(task: PreparedRun | list[PreparedRun]) -> list[str]:
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
    done = checkpoint_places.resumable_steps(
        store, {r for task in tasks for r in task_ids(task)}, batches=carried_batches
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


DEFAULT_GPU_BATCH = 64  # members per batch on a GPU when --batch is not given


def gpu_requested(device: str, missing: list[PreparedRun], gpu_workers: int | None) -> bool:
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
        carried = sum(checkpoint_places.resumable_steps(store, {p.run_id for p in runs}).values())
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
    for kept in checkpoint_places.kept(store):
        members = set(kept.members)
        if not asked & members:
            continue
        where = kept.note
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
    carried = sum(checkpoint_places.resumable_steps(store, {p.run_id for p in missing}).values())
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
