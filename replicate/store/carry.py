"""Carried checkpoints: an unfinished run or seed batch packed small enough to commit, so
that training goes on later, on this machine or another.

A checkpoint (``baselines.common.checkpoint``) is mostly its replay buffer: an Ant member
at 200k steps holds 180 MB of transitions. But every transition the env gave is fixed by
the env's seed and the actions taken (MuJoCo and dm-control are deterministic), so a
carried checkpoint keeps the actions and drops the observations, rewards and termination
flags; unpacking steps fresh envs through the actions again and checks the rebuilt replay
against the SHA-256 of the original, so a resumed run trains on exactly the data it had.
Everything else of the checkpoint (networks, optimisers, every random stream, the curve so
far) is kept as it was, xz-compressed, with the run directories' small files (spec, curve,
the parts trained so far) beside it.

Layout: ``<store>/carry/<batch id or run id>/`` holding ``manifest.json``,
``state.pt.xz``, ``actions-<k>.npy.xz`` per member and ``partial/<run id>/``.
``python -m replicate carry`` packs every unfinished checkpoint of a store. The carry is a
checkpoint place (``replicate.store.checkpoint_places``): the runner, through that interface only,
has a carried batch unpacked when it meets the batch without a local checkpoint (or with an
older one), and has it removed when the batch lands, never when it fails.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from replicate.errors import HarnessError
from replicate.store import provenance
from replicate.store.carry_format import (
    read_state,
    regenerate_batch_replay,
    sha256,
    write_state,
)
from replicate.store.place import CHECKPOINT_FILE, KeptCheckpoint
from replicate.store.run_recorder import (
    EARLIER_SEGMENTS_FILE,
    SEGMENTS_FILE,
    read_segments,
    write_segments,
)

CARRY_DIR = "carry"
FORMAT = 1
MANIFEST_FILE = "manifest.json"
# what a run directory has mid-training (segments under either name: older stores' too)
RUN_FILES = ("spec.json", "curve.csv", SEGMENTS_FILE, EARLIER_SEGMENTS_FILE)
BATCH_FILES = (SEGMENTS_FILE, EARLIER_SEGMENTS_FILE, "members.json")


class CarryError(HarnessError):
    """A checkpoint that cannot be carried, or a carried one that does not unpack here."""


@dataclass(frozen=True)
class Packed:
    name: str  # the batch id or run id
    step: int
    members: int
    bytes: int  # of the carried directory


def carry_root(store: Path) -> Path:
    return Path(store) / CARRY_DIR


def _run_spec(work_dir: Path) -> dict[str, Any]:
    return json.loads((work_dir / "spec.json").read_text())


def batch_members(store: Path, ident: str) -> list[str]:
    """The run ids of batch ``ident``, in its order, from the ``members.json`` the runner
    writes into the batch's directory."""
    listed = Path(store) / f".{ident}" / "members.json"
    if not listed.is_file():
        raise CarryError(
            f"{ident} does not list its members (started before the runner wrote members.json)",
            "let the batch finish where it is",
        )
    return json.loads(listed.read_text())


def _copy_files(source: Path, target: Path, names: tuple[str, ...]) -> None:
    """Copy the small files a resume reads. The runner rewrites them in place while it
    trains, so a JSON file caught mid-write is copied again until it parses."""
    target.mkdir(parents=True, exist_ok=True)
    for name in names:
        if not (source / name).is_file():
            continue
        for _ in range(20):
            shutil.copy2(source / name, target / name)
            if not name.endswith(".json"):
                break
            try:
                json.loads((target / name).read_text())
                break
            except ValueError:
                time.sleep(0.1)
        else:
            raise CarryError(f"{source / name} does not parse", "pack again")


def _is_done(store: Path, run_id: str) -> bool:
    return (Path(store) / run_id / "provenance.json").is_file()


def _finish_pack(
    store: Path, name: str, members: list[str], source: Path, build: Callable[[Path], None]
) -> Path:
    """Build the carried directory aside, then swap it in: a kill mid-pack leaves the last
    carried version whole. A run that landed while it packed is not carried."""
    root = carry_root(store)
    root.mkdir(parents=True, exist_ok=True)
    _recover(root, name)
    aside = root / f".{name}.packing"
    shutil.rmtree(aside, ignore_errors=True)
    aside.mkdir()
    try:
        build(aside)
        if not source.is_file() or any(_is_done(store, r) for r in members):
            raise CarryError(f"{name} finished while it was packed", "nothing to carry")
        final = root / name
        old = root / f".{name}.old"
        shutil.rmtree(old, ignore_errors=True)
        if final.exists():
            os.replace(final, old)
        os.replace(aside, final)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(aside, ignore_errors=True)
    return final


def _manifest(
    kind: str, name: str, env_id: str, step: int, members: list[str], seeds: list[int], digest: str
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "kind": kind,
        "name": name,
        "env_id": env_id,
        "step": step,
        "members": members,
        "seeds": seeds,
        "replay_sha256": digest,
        "packed_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "git_revision": provenance.git_revision(),
        "cpu_model": provenance.cpu_model(),
    }


def _not_behind(store: Path, name: str, step: int) -> None:
    """Refuse to pack over a carried version that is as far on or further (another machine
    trained on and packed it again while this one kept its older checkpoint)."""
    path = carried(store, name)
    if path is not None:
        at = json.loads((path / MANIFEST_FILE).read_text())["step"]
        if at >= step:
            raise CarryError(
                f"{name} is carried at step {at:,} already (its checkpoint "
                f"here is at step {step:,})",
                "nothing to pack",
            )


def _load(path: Path) -> dict[str, Any]:
    import torch

    return torch.load(path, weights_only=False, map_location="cpu")


def pack_batch(store: Path, ident: str, progress: bool = False) -> Packed:
    """Carry the checkpoint of seed batch ``ident`` (``<store>/.<ident>/``)."""
    store = Path(store)
    batch_dir = store / f".{ident}"
    checkpoint = _load(batch_dir / CHECKPOINT_FILE)
    members = batch_members(store, ident)
    work_dirs = [store / f".partial-{run_id}" for run_id in members]
    env_id = _run_spec(work_dirs[0])["env_id"]
    seeds, step = list(checkpoint["seeds"]), int(checkpoint["step"])
    _not_behind(store, ident, step)
    if "data" not in (checkpoint.get("buffer") or {}):  # PPO, DDPGfD: loops of their own
        raise CarryError(
            f"{ident}'s checkpoint has no replay of the SAC family's layout",
            "let it finish here",
        )
    data = checkpoint["buffer"]["data"].numpy()
    if not checkpoint["alive"].all():
        raise CarryError(f"{ident} has a failed member", "let the batch finish where it is")
    if data.shape[1] != step:
        raise CarryError(
            f"{ident}'s replay holds {data.shape[1]} transitions after {step} "
            "steps (preloaded with demonstrations, or wrapped around)",
            "let the batch finish where it is",
        )
    obs_dim = checkpoint["obs"].shape[1]  # a row is (s, a, r, s', terminated)
    act_dim = data.shape[2] - 2 - 2 * obs_dim
    actions = np.ascontiguousarray(data[:, :, obs_dim : obs_dim + act_dim])
    rebuilt, _, _ = regenerate_batch_replay(env_id, seeds, actions, progress)
    if not np.array_equal(rebuilt, data):
        raise CarryError(
            f"{ident}'s replay does not come back from its actions here",
            "let the batch finish where it is",
        )
    carried_state = dict(checkpoint)
    carried_state["buffer"] = {"position": checkpoint["buffer"]["position"]}

    def build(target: Path) -> None:
        write_state(target, carried_state, actions)
        _copy_files(batch_dir, target / "batch", (SEGMENTS_FILE, EARLIER_SEGMENTS_FILE))
        (target / "batch" / "members.json").write_text(json.dumps(members) + "\n")
        for run_id, work in zip(members, work_dirs):
            _copy_files(work, target / "partial" / run_id, RUN_FILES)
        (target / MANIFEST_FILE).write_text(
            json.dumps(
                _manifest("batch", ident, env_id, step, members, seeds, sha256(data)), indent=1
            )
            + "\n"
        )

    final = _finish_pack(store, ident, members, batch_dir / CHECKPOINT_FILE, build)
    return Packed(ident, step, len(members), _size(final))


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def unfinished(store: Path) -> list[tuple[str, str]]:
    """(kind, name) of every checkpoint in the store: seed batches (a run training alone is
    a batch of one)."""
    store = Path(store)
    return [("batch", p.parent.name[1:]) for p in sorted(store.glob(".batch-*/" + CHECKPOINT_FILE))]


def prune(store: Path) -> list[str]:
    """Forget every carried run or batch of which a run has landed in the store (it finished
    on a machine that kept its own checkpoint, say; a batch resumes only with all its
    members); the names forgotten."""
    gone = [m["name"] for m in listing(store) if any(_is_done(store, r) for r in m["members"])]
    for name in gone:
        discard(store, name)
    return gone


def _pack_one(store: Path, kind: str, name: str, progress: bool) -> Packed | str:
    """One item of ``pack_all``: what was packed, or the line that says why not."""
    try:
        return pack_batch(store, name, progress)
    except CarryError as exc:
        return str(exc)
    except (KeyError, TypeError, AttributeError) as exc:  # a loop with its own layout
        return (
            f"{name}'s checkpoint has no replay of the SAC family's layout "
            f"({type(exc).__name__}: {exc}); fix: let it finish where it is"
        )
    except Exception as exc:  # it landed or was removed while we looked, or will not load
        return f"{name}: {type(exc).__name__}: {exc}; fix: pack again, or let it finish"


def pack_all(
    store: Path, progress: bool = False, workers: int = 1
) -> tuple[list[Packed], list[str]]:
    """Carry every checkpoint of the store, ``workers`` at a time (rebuilding a replay to
    check it steps MuJoCo once per transition: minutes for a 300k-step Ant batch); the
    packed ones, and a line per one that could not be carried."""
    prune(store)
    items = unfinished(store)
    if workers > 1 and len(items) > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(min(workers, len(items)), mp.get_context("spawn")) as pool:
            results = list(
                pool.map(_pack_one, [store] * len(items), *zip(*items), [False] * len(items))
            )
    else:
        results = [_pack_one(store, kind, name, progress) for kind, name in items]
    return (
        [r for r in results if isinstance(r, Packed)],
        [r for r in results if isinstance(r, str)],
    )


# -- unpacking ----------------------------------------------------------------------------


def _recover(root: Path, name: str) -> None:
    """Put back a carried directory that a kill mid-swap left as ``.<name>.old``."""
    old = root / f".{name}.old"
    if not (root / name).exists() and (old / MANIFEST_FILE).is_file():
        os.replace(old, root / name)


def carried(store: Path, name: str) -> Path | None:
    _recover(carry_root(store), name)
    path = carry_root(store) / name
    return path if (path / MANIFEST_FILE).is_file() else None


def should_unpack(store: Path, name: str, local_checkpoint: Path) -> bool:
    """Whether carried ``name`` replaces the local checkpoint: where there is none, or where
    the carried one is further on (another machine trained on and packed it again)."""
    path = carried(store, name)
    if path is None:
        return False
    if not local_checkpoint.is_file():
        return True
    step = json.loads((path / MANIFEST_FILE).read_text())["step"]
    import torch  # only here: the dry run and the reports read the carry without torch

    # mapped, not read: a batch checkpoint's replay is hundreds of MB
    local = torch.load(local_checkpoint, weights_only=False, map_location="cpu", mmap=True)
    return step > int(local["step"])


def _load_carried(path: Path, kind: str) -> tuple[dict[str, Any], dict[str, Any], np.ndarray]:
    manifest = json.loads((path / MANIFEST_FILE).read_text())
    if manifest.get("format") != FORMAT or manifest.get("kind") != kind:
        raise CarryError(
            f"{path} is not a carried {kind} of format {FORMAT}",
            f"delete {path} to start the {kind} over",
        )
    state, actions = read_state(path, len(manifest["members"]))
    return manifest, state, actions


ACCEPT_REBUILT = "REPLICATE_CARRY_ACCEPT_REBUILT"  # set to 1: resume on a replay that differs


def _check_rebuilt(path: Path, manifest: dict[str, Any], digest: str) -> str:
    """How the rebuilt replay compares with the packed one, for the runs' records; raises
    where it differs, unless the user accepts that."""
    if digest == manifest["replay_sha256"]:
        return "rebuilt bit for bit"
    if os.environ.get(ACCEPT_REBUILT) == "1":
        return f"rebuilt differently here, accepted ({ACCEPT_REBUILT}=1)"
    raise CarryError(
        f"the carried {manifest['kind']} {manifest['name']} did not rebuild its replay on this "
        f"machine (packed on {manifest['cpu_model']}; the envs stepped differently here)",
        f"resume it on a machine like that one, set {ACCEPT_REBUILT}=1 to resume on the "
        f"replay as rebuilt here, or delete {path} (the run then resumes from a checkpoint "
        "of this store's own, or starts over)",
    )


def _note_carried(work: Path, manifest: dict[str, Any], replay: str) -> None:
    """Mark the last stretch of an unpacked run's training: where it was packed, and its
    replay."""
    segments = read_segments(work)
    if segments:
        segments[-1]["carried"] = {
            "step": manifest["step"],
            "packed_on": manifest["cpu_model"],
            "unpacked_on": provenance.cpu_model(),
            "replay": replay,
        }
        write_segments(work, segments)


def unpack_batch(store: Path, ident: str) -> bool:
    """Put carried batch ``ident`` back as ``<store>/.<ident>/checkpoint.pt`` and its
    members' unfinished run directories; False when nothing of it is carried."""
    path = carried(store, ident)
    if path is None:
        return False
    import torch

    manifest, state, actions = _load_carried(path, "batch")
    data, envs, obs = regenerate_batch_replay(manifest["env_id"], manifest["seeds"], actions)
    replay = _check_rebuilt(path, manifest, sha256(data))
    if replay != "rebuilt bit for bit":  # the envs go on from where they stepped here
        state["envs"], state["obs"] = envs, obs
    state["buffer"] = {"data": torch.from_numpy(data), "position": state["buffer"]["position"]}
    store = Path(store)
    batch_dir = store / f".{ident}"
    _copy_files(path / "batch", batch_dir, BATCH_FILES)
    for run_id in manifest["members"]:
        _copy_files(path / "partial" / run_id, store / f".partial-{run_id}", RUN_FILES)
        _note_carried(store / f".partial-{run_id}", manifest, replay)
    _write_checkpoint(batch_dir / CHECKPOINT_FILE, state)
    return True


def _write_checkpoint(path: Path, state: dict[str, Any]) -> None:
    from baselines.common.checkpoint import save_checkpoint

    save_checkpoint(path, state)


def discard(store: Path, name: str) -> None:
    """Forget carried ``name`` (its run or batch has landed)."""
    shutil.rmtree(carry_root(store) / name, ignore_errors=True)


def listing(store: Path) -> list[dict[str, Any]]:
    """The manifests of everything carried in the store."""
    root = carry_root(store)
    if not root.is_dir():
        return []
    for old in root.glob(".*.old"):
        _recover(root, old.name[1:].removesuffix(".old"))
    return [
        json.loads((p / MANIFEST_FILE).read_text())
        for p in sorted(root.iterdir())
        if not p.name.startswith(".") and (p / MANIFEST_FILE).is_file()
    ]


class CarryPlace:
    """The carry as a checkpoint place (``replicate.store.place``)."""

    def kept(self, store: Path) -> list[KeptCheckpoint]:
        return [
            KeptCheckpoint(
                name=m["name"],
                members=tuple(m["members"]),
                step=int(m["step"]),
                where=carry_root(store),
                note=f"carried: {m['kind']} {m['name']} at step {m['step']:,} "
                f"(packed {m['packed_utc']} on {m['cpu_model']})",
            )
            for m in listing(store)
        ]

    def fetch(self, store: Path, name: str, checkpoint: Path) -> None:
        if should_unpack(store, name, checkpoint):
            unpack_batch(store, name)  # packed before, maybe on another machine

    def landed(self, store: Path, names: list[str]) -> None:
        for name in names:
            discard(store, name)

    def tidy(self, store: Path) -> None:
        prune(store)
