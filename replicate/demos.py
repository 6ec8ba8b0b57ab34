"""Demonstration files: making, saving, and loading them with validation.

A demonstration file is a ``.npz`` with three entries, read without pickle:

- ``observations``: (n, obs_dim) float32
- ``actions``: (n, act_dim) float32
- ``metadata``: a JSON string (env id and version, number of pairs, expert returns, how it
  was made, the command that regenerates it, and a SHA-256 of the two arrays)

Loading checks everything it can and refuses a file with a one-line :class:`DemoError`.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from envs import env_spec, make_env
from replicate.errors import DemoError

FORMAT_VERSION = 1
DEMO_DATA_DIR = "data/demos"


@dataclass
class Demonstrations:
    observations: np.ndarray
    actions: np.ndarray
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def mean_return(self) -> float:
        return float(self.metadata["expert_return_mean"])

    @property
    def sha256(self) -> str:
        return content_sha256(self.observations, self.actions)


def content_sha256(observations: np.ndarray, actions: np.ndarray) -> str:
    digest = hashlib.sha256()
    for array in (observations, actions):
        digest.update(np.ascontiguousarray(array, dtype="<f4").tobytes())
    return digest.hexdigest()


def default_demo_path(env_id: str) -> Path:
    """Where the committed demonstrations of ``env_id`` live inside the package."""
    name = f"{env_id.replace('/', '__')}.v{FORMAT_VERSION}.npz"
    return Path(str(resources.files("replicate").joinpath(DEMO_DATA_DIR, name)))


def save_demos(path: Path, demos: Demonstrations) -> Path:
    """Write atomically (temp file + rename), stamping the content hash into the metadata."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    metadata = dict(demos.metadata, content_sha256=demos.sha256, format_version=FORMAT_VERSION)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.partial")
    os.close(fd)
    try:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, observations=demos.observations.astype(np.float32),
                                actions=demos.actions.astype(np.float32),
                                metadata=np.array(json.dumps(metadata, indent=1, sort_keys=True)))
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    demos.metadata = metadata
    return path


def load_demos(path: Path | str, env_id: str) -> Demonstrations:
    """Load and validate demonstrations for ``env_id``; raise :class:`DemoError` on any problem."""
    path = Path(path)
    if env_id in RULE_EXPERTS:
        regenerate = f"regenerate it with `python -m replicate demos --env {env_id} --out {path}`"
    else:
        regenerate = (f"pass --demos PATH to a valid demonstration file for {env_id} "
                      "(the harness has no expert for this env yet)")
    if not path.is_file():
        raise DemoError(f"demonstration file {path} not found", regenerate)
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = {"observations", "actions", "metadata"} - set(data.files)
            if missing:
                raise DemoError(f"demonstration file {path} lacks {sorted(missing)}", regenerate)
            observations, actions = data["observations"], data["actions"]
            metadata = json.loads(str(data["metadata"]))
    except DemoError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as exc:
        raise DemoError(f"demonstration file {path} is malformed or truncated "
                        f"({type(exc).__name__}: {exc})".replace("\n", " "), regenerate) from None

    spec = env_spec(env_id)
    if metadata.get("env_id") != env_id:
        raise DemoError(f"demonstration file {path} is for env '{metadata.get('env_id')}', "
                        f"not '{env_id}'", f"pass the demonstrations of {env_id}, or {regenerate}")
    if observations.ndim != 2 or actions.ndim != 2 or len(observations) != len(actions):
        raise DemoError(f"demonstration file {path} has arrays of shapes {observations.shape} "
                        f"and {actions.shape}; expected (n, obs_dim) and (n, act_dim)", regenerate)
    if observations.shape[1] != spec.obs_dim or actions.shape[1] != spec.act_dim:
        raise DemoError(f"demonstration file {path} has obs/action dims "
                        f"{observations.shape[1]}/{actions.shape[1]} but {env_id} has "
                        f"{spec.obs_dim}/{spec.act_dim}", regenerate)
    if len(observations) == 0:
        raise DemoError(f"demonstration file {path} holds no pairs", regenerate)
    if not (np.isfinite(observations).all() and np.isfinite(actions).all()):
        raise DemoError(f"demonstration file {path} contains NaN or inf values", regenerate)
    if metadata.get("n_pairs") != len(observations):
        raise DemoError(f"demonstration file {path} declares {metadata.get('n_pairs')} pairs "
                        f"but holds {len(observations)}", regenerate)
    demos = Demonstrations(observations.astype(np.float32), actions.astype(np.float32), metadata)
    if metadata.get("content_sha256") != demos.sha256:
        raise DemoError(f"demonstration file {path} does not match its content hash "
                        "(edited or corrupted)", regenerate)
    if not np.isfinite(metadata.get("expert_return_mean", np.nan)):
        raise DemoError(f"demonstration file {path} has no finite expert_return_mean", regenerate)
    return demos


def mountaincar_rule(obs: np.ndarray) -> np.ndarray:
    """The paper's hand-made MountainCar expert: push with -0.5 when moving left, else +0.5."""
    return np.array([-0.5 if obs[1] < 0 else 0.5], dtype=np.float32)


def rollout_rule_demos(env_id: str, rule, n_pairs: int, seed: int, command: str,
                       description: str) -> Demonstrations:
    """Roll whole episodes of ``rule`` until ``n_pairs`` pairs exist; keep the first ``n_pairs``.

    The expert return is measured over every episode rolled, all of them complete.
    """
    if n_pairs <= 0:
        raise DemoError(f"number of demonstration pairs must be positive, got {n_pairs}",
                        "pass --pairs 1000 (the paper's number)")
    env = make_env(env_id, seed=seed)
    observations, actions, episode_returns = [], [], []
    obs, _ = env.reset(seed=seed)
    while len(observations) < n_pairs:
        done, total = False, 0.0
        while not done:
            action = rule(obs)
            observations.append(obs)
            actions.append(action)
            obs, reward, terminated, truncated, _ = env.step(action)
            total += reward
            done = terminated or truncated
        episode_returns.append(total)
        obs, _ = env.reset()
    env.close()
    import gymnasium

    metadata = {
        "env_id": env_id,
        "env_version": f"{env_id} (gymnasium {gymnasium.__version__})",
        "n_pairs": n_pairs,
        "obs_dim": int(np.shape(observations[0])[0]),
        "act_dim": int(np.shape(actions[0])[0]),
        "expert": description,
        "expert_episodes": len(episode_returns),
        "expert_returns": [round(r, 4) for r in episode_returns],
        "expert_return_mean": float(np.mean(episode_returns)),
        "expert_return_std": float(np.std(episode_returns)),
        "seed": seed,
        "command": command,
    }
    return Demonstrations(np.asarray(observations[:n_pairs], dtype=np.float32),
                          np.asarray(actions[:n_pairs], dtype=np.float32), metadata)


RULE_EXPERTS = {
    "MountainCarContinuous-v0": (
        mountaincar_rule,
        "hand-made rule from the paper: action -0.5 when velocity < 0, else +0.5"),
}


def make_demos(env_id: str, n_pairs: int = 1000, seed: int = 0) -> Demonstrations:
    """Demonstrations for ``env_id`` from the harness's own experts (rule experts for now)."""
    env_spec(env_id)  # unknown ids fail here with the list of known ones
    if env_id not in RULE_EXPERTS:
        raise DemoError(f"no expert is available yet to make demonstrations for {env_id}",
                        f"use one of {sorted(RULE_EXPERTS)} or pass --demos with your own file")
    rule, description = RULE_EXPERTS[env_id]
    command = (f"python -m replicate demos --env {env_id} --pairs {n_pairs} --seed {seed}")
    return rollout_rule_demos(env_id, rule, n_pairs, seed, command, description)
