"""Demonstration files: making, saving, and loading them with validation.

A demonstration file is a ``.npz`` read without pickle. The paper's demonstrations are
(s, a) pairs; DDPGfD also needs what followed each pair, so the harness stores it too:

- ``observations``: (n, obs_dim) float32 and ``actions``: (n, act_dim) float32
- optional, all or none: ``rewards`` (n,), ``next_observations`` (n, obs_dim),
  ``terminated`` (n,) and ``truncated`` (n,) of the step taken from each pair
- ``metadata``: a JSON string (env id and version, number of pairs, expert returns, how it
  was made, the command that regenerates it, and a SHA-256 of all the arrays)

Loading checks everything it can and refuses a file with a one-line :class:`DemoError`.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from envs import env_spec, make_env
from replicate.errors import DemoError

FORMAT_VERSION = 1
# Demonstration rollouts seed their env from here up, apart from every training seed
# (0, 1, ...) and evaluation seed (10,000 + seed): otherwise training seed 0 would start
# its episodes from exactly the demonstrations' start states.
DEMO_SEED_OFFSET = 1_000_000
DEMO_DATA_DIR = "data/demos"


TRANSITION_ARRAYS = ("rewards", "next_observations", "terminated", "truncated")


@dataclass
class Demonstrations:
    observations: np.ndarray
    actions: np.ndarray
    metadata: dict[str, Any] = field(default_factory=dict)
    rewards: np.ndarray | None = None
    next_observations: np.ndarray | None = None
    terminated: np.ndarray | None = None
    truncated: np.ndarray | None = None

    @property
    def mean_return(self) -> float:
        return float(self.metadata["expert_return_mean"])

    @property
    def has_transitions(self) -> bool:
        return self.rewards is not None

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array present, by its name in the file."""
        named = {"observations": self.observations, "actions": self.actions}
        if self.has_transitions:
            named.update({name: getattr(self, name) for name in TRANSITION_ARRAYS})
        return named

    @property
    def sha256(self) -> str:
        return content_sha256(self.arrays())


def content_sha256(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 over the arrays in a fixed order, as little-endian float32."""
    digest = hashlib.sha256()
    for name in ("observations", "actions", *TRANSITION_ARRAYS):
        if name in arrays:
            digest.update(np.ascontiguousarray(arrays[name], dtype="<f4").tobytes())
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
            arrays = {
                name: np.asarray(values, dtype=np.float32)
                for name, values in demos.arrays().items()
            }
            np.savez_compressed(
                handle, **arrays, metadata=np.array(json.dumps(metadata, indent=1, sort_keys=True))
            )
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a demonstration file is shared
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
        regenerate = (
            f"pass --demos PATH to a valid demonstration file for {env_id} "
            "(the harness has no expert for this env yet)"
        )
    if not path.is_file():
        raise DemoError(f"demonstration file {path} not found", regenerate)
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = {"observations", "actions", "metadata"} - set(data.files)
            if missing:
                raise DemoError(f"demonstration file {path} lacks {sorted(missing)}", regenerate)
            observations, actions = data["observations"], data["actions"]
            metadata = json.loads(str(data["metadata"]))
            present = [name for name in TRANSITION_ARRAYS if name in data.files]
            if present and len(present) != len(TRANSITION_ARRAYS):
                raise DemoError(
                    f"demonstration file {path} holds {present} but not all of "
                    f"{list(TRANSITION_ARRAYS)}",
                    regenerate,
                )
            transitions = {name: data[name] for name in present}
    except DemoError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as exc:
        raise DemoError(
            f"demonstration file {path} is malformed or truncated "
            f"({type(exc).__name__}: {exc})".replace("\n", " "),
            regenerate,
        ) from None

    spec = env_spec(env_id)
    if metadata.get("env_id") != env_id:
        raise DemoError(
            f"demonstration file {path} is for env '{metadata.get('env_id')}', not '{env_id}'",
            f"pass the demonstrations of {env_id}, or {regenerate}",
        )
    if observations.ndim != 2 or actions.ndim != 2 or len(observations) != len(actions):
        raise DemoError(
            f"demonstration file {path} has arrays of shapes {observations.shape} "
            f"and {actions.shape}; expected (n, obs_dim) and (n, act_dim)",
            regenerate,
        )
    if observations.shape[1] != spec.obs_dim or actions.shape[1] != spec.act_dim:
        raise DemoError(
            f"demonstration file {path} has obs/action dims "
            f"{observations.shape[1]}/{actions.shape[1]} but {env_id} has "
            f"{spec.obs_dim}/{spec.act_dim}",
            regenerate,
        )
    if len(observations) == 0:
        raise DemoError(f"demonstration file {path} holds no pairs", regenerate)
    if transitions:
        n, expected = (
            len(observations),
            {
                "rewards": (len(observations),),
                "next_observations": observations.shape,
                "terminated": (len(observations),),
                "truncated": (len(observations),),
            },
        )
        for name, shape in expected.items():
            if transitions[name].shape != shape:
                raise DemoError(
                    f"demonstration file {path} has {name} of shape "
                    f"{transitions[name].shape}, expected {shape} for {n} pairs",
                    regenerate,
                )
    if not all(np.isfinite(a).all() for a in (observations, actions, *transitions.values())):
        raise DemoError(f"demonstration file {path} contains NaN or inf values", regenerate)
    if metadata.get("n_pairs") != len(observations):
        raise DemoError(
            f"demonstration file {path} declares {metadata.get('n_pairs')} pairs "
            f"but holds {len(observations)}",
            regenerate,
        )
    transitions = {
        name: np.asarray(values, dtype=np.float32) for name, values in transitions.items()
    }
    demos = Demonstrations(
        observations.astype(np.float32), actions.astype(np.float32), metadata, **transitions
    )
    if metadata.get("content_sha256") != demos.sha256:
        raise DemoError(
            f"demonstration file {path} does not match its content hash (edited or corrupted)",
            regenerate,
        )
    if not np.isfinite(metadata.get("expert_return_mean", np.nan)):
        raise DemoError(f"demonstration file {path} has no finite expert_return_mean", regenerate)
    return demos


def mountaincar_rule(obs: np.ndarray) -> np.ndarray:
    """The paper's hand-made MountainCar expert: push with -0.5 when moving left, else +0.5."""
    return np.array([-0.5 if obs[1] < 0 else 0.5], dtype=np.float32)


def rollout_demos(
    env_id: str,
    rule: Callable[[np.ndarray], np.ndarray],
    n_pairs: int,
    seed: int,
    command: str,
    description: str,
    min_episodes: int = 1,
    extra_metadata: dict[str, Any] | None = None,
) -> Demonstrations:
    """Roll whole episodes of ``rule`` until ``n_pairs`` pairs and ``min_episodes`` episodes
    exist; keep the first ``n_pairs`` pairs.

    The expert return is measured over every episode rolled, all of them complete.
    """
    if n_pairs <= 0:
        raise DemoError(
            f"number of demonstration pairs must be positive, got {n_pairs}",
            "pass --pairs 1000 (the paper's number)",
        )
    env_seed = DEMO_SEED_OFFSET + seed
    env = make_env(env_id, seed=env_seed)
    observations, actions, episode_returns = [], [], []
    rewards, next_observations, terminals, truncations = [], [], [], []
    obs, _ = env.reset(seed=env_seed)
    while len(observations) < n_pairs or len(episode_returns) < min_episodes:
        done, total = False, 0.0
        while not done:
            action = rule(obs)
            observations.append(obs)
            actions.append(action)
            obs, reward, terminated, truncated, _ = env.step(action)
            rewards.append(reward)
            next_observations.append(obs)
            terminals.append(terminated)
            truncations.append(truncated)
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
        "env_seed": env_seed,
        "command": command,
        **(extra_metadata or {}),
    }

    def first(values: list) -> np.ndarray:
        return np.asarray(values[:n_pairs], dtype=np.float32)

    return Demonstrations(
        first(observations),
        first(actions),
        metadata,
        rewards=first(rewards),
        next_observations=first(next_observations),
        terminated=first(terminals),
        truncated=first(truncations),
    )


RULE_EXPERTS = {
    "MountainCarContinuous-v0": (
        mountaincar_rule,
        "hand-made rule from the paper: action -0.5 when velocity < 0, else +0.5",
    ),
}
