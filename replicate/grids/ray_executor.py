"""The Ray executor: a grid's missing runs as tasks on an existing Ray cluster, one CPU
each. Ray is imported only when a grid trains there."""

from __future__ import annotations

import time
from pathlib import Path

from tqdm import tqdm

from baselines.common.checkpoint import TimeLimitReached, past
from replicate.errors import HarnessError
from replicate.grids.planning import estimate_minutes
from replicate.store import checkpoint_places
from replicate.store.runner import PreparedRun, execute


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


def run_on_ray(
    prepared: list[PreparedRun],
    missing: list[PreparedRun],
    store: Path,
    address: str | None,
    checkpoint_interval: int,
    device: str = "auto",
    deadline: float | None = None,
) -> tuple[float, list[tuple[str, str]], list[str], list[str]]:
    """One Ray task per missing run, one CPU each. The store must be a path every node
    sees (a shared filesystem), and every node needs this project installed. Returns when
    training started (``time.time()``), the (run id, reason) of the runs that failed, and
    the ids of those that checkpointed at ``deadline`` and of those that did not start."""
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
        k.name
        for k in checkpoint_places.kept(store)
        if len(k.members) > 1 and asked & set(k.members)
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
    return started, failed, stopped, not_started
