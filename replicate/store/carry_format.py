"""The carried checkpoint's format: a seed batch's replay rebuilt from its actions, and the
checkpoint's state and the members' actions written xz-compressed (see
``replicate.store.carry``)."""

from __future__ import annotations

import hashlib
import io
import lzma
import os
from pathlib import Path
from typing import Any

import numpy as np

STATE_FILE = "state.pt.xz"
ACTIONS_FILE = "actions-{}.npy.xz"  # member k's actions


def sha256(array: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()


# -- rebuilding a replay from its actions -------------------------------------------------


def _steps(count: int, what: str, progress: bool) -> Any:
    from tqdm import tqdm

    return tqdm(
        range(count),
        desc=f"rebuilding {what}",
        unit="step",
        leave=False,
        mininterval=1.0,
        disable=not progress,
        dynamic_ncols=True,
    )


def regenerate_batch_replay(
    env_id: str, seeds: list[int], actions: np.ndarray, progress: bool = False
) -> tuple[np.ndarray, list[Any], np.ndarray]:
    """The stacked replay rows (members, steps, 2 obs + act + 2) that a seed batch's envs
    produce when stepped through ``actions`` (members, steps, act_dim) from their seeds, as
    ``baselines.offpolicy.run_off_policy`` steps them (every member alive); with the
    envs' snapshot and observations where the actions leave them."""
    import torch

    from baselines.common.stacked import StackedReplay
    from envs.vector import EnvBatch

    n, steps, act_dim = actions.shape
    envs = EnvBatch(env_id, seeds)
    try:
        replay = StackedReplay(n, envs.obs_dim, act_dim, max(steps, 1), torch.device("cpu"))
        obs = envs.reset(seeds=seeds)
        for t in _steps(steps, f"{env_id} seeds {seeds}", progress):
            result = envs.step(actions[:, t])
            replay.add(obs, actions[:, t], result.rewards, result.next_obs, result.terminated)
            obs = result.obs
        snapshot = envs.snapshot()
    finally:
        envs.close()
    return replay.data[:, :steps].numpy(), snapshot, obs


def _write_xz(path: Path, payload: bytes) -> None:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_bytes(lzma.compress(payload, preset=6))
    os.replace(tmp, path)


def write_state(target: Path, state: dict[str, Any], actions: np.ndarray) -> None:
    """The checkpoint without its replay, and each member's actions in a file of its own
    (a paper-budget member's are 32 MB; one file per member keeps every file small)."""
    import torch

    raw = io.BytesIO()
    torch.save(state, raw)
    _write_xz(target / STATE_FILE, raw.getvalue())
    for k, member_actions in enumerate(actions):
        raw = io.BytesIO()
        np.save(raw, np.ascontiguousarray(member_actions, dtype=np.float32))
        _write_xz(target / ACTIONS_FILE.format(k), raw.getvalue())


def read_state(path: Path, members: int) -> tuple[dict[str, Any], np.ndarray]:
    import torch

    state = torch.load(
        io.BytesIO(lzma.decompress((path / STATE_FILE).read_bytes())),
        weights_only=False,
        map_location="cpu",
    )
    actions = np.stack(
        [
            np.load(io.BytesIO(lzma.decompress((path / ACTIONS_FILE.format(k)).read_bytes())))
            for k in range(members)
        ]
    )
    return state, actions
