"""The commands of ``python -m replicate`` that train or list single runs, experts and
demonstrations, and carry the store's unfinished checkpoints: their options and handlers."""

from __future__ import annotations

import argparse
import ast
from pathlib import Path
from typing import Any

from replicate.grids.options import (
    STORE_HELP,
    Command,
    HelpFormatter,
    add_device_argument,
    positive_int,
)


def _seed_list(text: str) -> list[int]:
    """``1-8`` or ``1,4,7`` (or a mix: ``1-3,9``) as a list of seeds."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            first, _, last = part.partition("-")
            seeds.extend(range(int(first), int(last or first) + 1))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a seed list: '{text}' (e.g. 1-8 or 1,4,7)") from None
    if not seeds:
        raise argparse.ArgumentTypeError(f"no seeds in '{text}'")
    return seeds


def _parse_overrides(pairs: list[str]) -> dict:
    """``KEY=VALUE`` strings to a dict; values are Python literals where they parse as one."""
    from replicate.errors import HarnessError

    overrides = {}
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        if not sep or not key:
            raise HarnessError(
                f"--set expects KEY=VALUE, got '{pair}'", "write it like --set guide_threshold=0.1"
            )
        try:
            overrides[key] = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            overrides[key] = raw
    return overrides


def _declare_train(sub: Any) -> None:
    train = sub.add_parser(
        "train",
        help="train one run, or a seed batch, into the run store",
        description="Train one run (algorithm x env x seed x budget) into the run store, "
        "with a progress bar. A run whose resolved spec is already complete in "
        "the store is not trained again. With --seeds K: seeds SEED to SEED+K-1; "
        "with --batch N as well, up to N of them train together in one process "
        "as a seed batch (algorithms of the SAC family; each seed's curve is "
        "the one it draws alone), e.g. --seed 0 --seeds 8 --batch 4 --workers 2.",
        formatter_class=HelpFormatter,
    )
    train.add_argument(
        "--algo", required=True, help="algorithm name; `python -m replicate algos` lists them"
    )
    train.add_argument(
        "--env",
        required=True,
        help="environment id, e.g. MountainCarContinuous-v0 or Hopper-v5; "
        "`python -m replicate envs` lists them",
    )
    train.add_argument(
        "--steps", type=int, required=True, help="training budget in environment steps (> 0)"
    )
    train.add_argument(
        "--seed", type=int, default=0, help="seed of env, weights, exploration and replay sampling"
    )
    train.add_argument(
        "--seeds",
        type=positive_int,
        default=1,
        help="how many seeds to train, from --seed up (default: 1)",
    )
    train.add_argument(
        "--batch",
        type=positive_int,
        default=None,
        help="with --seeds: train up to this many seeds together in one process "
        "(a seed batch); default: one seed per process on CPU",
    )
    train.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="with --seeds: processes training at once (default: one per core)",
    )
    train.add_argument(
        "--eval-interval",
        type=int,
        default=None,
        help="env steps between evaluations (default: steps/20, at least 1)",
    )
    train.add_argument(
        "--eval-episodes",
        type=int,
        default=5,
        help="deterministic-policy test episodes per evaluation",
    )
    train.add_argument(
        "--demos",
        default=None,
        help="demonstration file (.npz) for algorithms that use demonstrations; "
        "default: the committed file of the env",
    )
    train.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a hyperparameter, e.g. --set guide_threshold=0.1 "
        "(repeatable; `python -m replicate algos` shows them)",
    )
    train.add_argument("--store", type=Path, default=None, help=STORE_HELP)
    train.add_argument(
        "--checkpoint-interval",
        type=int,
        default=10_000,
        help="env steps between checkpoints (at the next episode end; 0: "
        "none); an interrupted run resumes from its last one",
    )
    add_device_argument(train)


def _declare_demos(sub: Any) -> None:
    demos = sub.add_parser(
        "demos",
        help="make a demonstration file from the harness's own expert",
        description="Roll out the expert of an env and save (s, a) pairs with provenance.",
        formatter_class=HelpFormatter,
    )
    which = demos.add_mutually_exclusive_group(required=True)
    which.add_argument("--env", help="environment id")
    which.add_argument(
        "--all",
        action="store_true",
        help="every env with an expert (the rule or a committed SAC expert); "
        "lists the envs skipped for want of one",
    )
    demos.add_argument("--pairs", type=int, default=1000, help="number of (s, a) pairs")
    demos.add_argument("--seed", type=int, default=0, help="seed of the expert rollouts")
    demos.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output file (default: the package's committed demonstration path)",
    )


def _declare_expert(sub: Any) -> None:
    expert = sub.add_parser(
        "expert",
        help="train (or resume) the harness's SAC expert of an env",
        description="Train the SAC expert of an env: one run per seed (several as one seed "
        "batch) in the run store --root/<env>/, checkpointed; started again, it resumes. "
        "The policy with the best evaluation of any of them is exported, with its "
        "provenance, to the package's expert file, from which `demos` rolls out "
        "demonstrations.",
        formatter_class=HelpFormatter,
    )
    expert.add_argument(
        "--env",
        default=None,
        help="environment id, e.g. Hopper-v5 (default: every env with a committed expert, "
        "one after another)",
    )
    expert.add_argument(
        "--steps",
        type=int,
        default=1_000_000,
        help="training budget in env steps (the SAC paper's 1M)",
    )
    expert.add_argument("--seed", type=int, default=0, help="seed of the expert run")
    expert.add_argument(
        "--seeds",
        type=_seed_list,
        default=None,
        help="train these seeds (e.g. 1-8 or 1,4,7) as one seed batch and keep the best "
        "member (instead of --seed)",
    )
    expert.add_argument(
        "--root",
        type=Path,
        default=Path("experts"),
        help="where the experts' run stores are (one per env)",
    )
    expert.add_argument(
        "--eval-interval",
        type=int,
        default=10_000,
        help="env steps between evaluations (the best one is kept)",
    )
    expert.add_argument(
        "--checkpoint-interval",
        type=int,
        default=10_000,
        help="env steps between checkpoints",
    )
    expert.add_argument(
        "--algo",
        choices=("sac", "sac-twin-q"),
        default=None,
        help="the trainer: the paper's V-network SAC, or twin-Q SAC with a "
        "learned temperature (default: sac, but sac-twin-q for the MuJoCo envs)",
    )
    expert.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads for the updates (an expert training alone may use "
        "every core; results then differ in rounding from 1 thread)",
    )
    add_device_argument(expert)
    expert.add_argument(
        "--export-only",
        action="store_true",
        help="do not train; export the best policy found so far",
    )
    expert.add_argument(
        "--minutes",
        type=float,
        default=None,
        help="checkpoint and stop after this many minutes of training, exporting the best "
        "policy so far (the same command goes on from there)",
    )


def _declare_carry(sub: Any) -> None:
    carry = sub.add_parser(
        "carry",
        help="pack the store's unfinished runs and batches small enough to commit",
        description="Pack every checkpoint of the store's unfinished runs and seed batches "
        "into <store>/carry/ without its replay buffer (rebuilt from the actions "
        "when unpacked, and checked against its SHA-256), so that it can be "
        "committed and resumed by the same command later, on this machine or "
        "another. Training may go on while it packs.",
        formatter_class=HelpFormatter,
    )
    carry.add_argument("--store", type=Path, default=None, help=STORE_HELP)
    carry.add_argument(
        "--list", action="store_true", help="list what is carried instead of packing"
    )
    carry.add_argument(
        "--workers",
        type=int,
        default=1,
        help="checkpoints packed at once (each rebuilds its replay on a core to check it)",
    )


def _declare_algos(sub: Any) -> None:
    sub.add_parser("algos", help="list algorithms and their default hyperparameters")


def _declare_envs(sub: Any) -> None:
    sub.add_parser("envs", help="list environments and their spec table")


def _cmd_train(args: argparse.Namespace) -> int:
    from replicate.store.runner import prepare
    from replicate.store.spec import RunSpec

    specs = [
        RunSpec(
            algo=args.algo,
            env_id=args.env,
            seed=seed,
            total_steps=args.steps,
            eval_interval=args.eval_interval or max(1, args.steps // 20),
            eval_episodes=args.eval_episodes,
            hyperparameters=_parse_overrides(args.overrides),
            demos=args.demos,
        )
        for seed in range(args.seed, args.seed + args.seeds)
    ]
    prepared = [prepare(spec) for spec in specs]  # a bad spec fails here, in one line
    if len(specs) == 1 and args.batch is None and args.workers is None:
        return _train_alone(prepared[0], args)
    return _train_seeds(specs, args)


def _train_alone(prepared: Any, args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from replicate.store.runner import execute

    with tqdm(
        total=prepared.spec.total_steps,
        unit="step",
        desc=prepared.run_id[:48],
        dynamic_ncols=True,
    ) as bar:
        run = execute(
            prepared,
            args.store,
            on_steps=bar.update,
            checkpoint_interval=args.checkpoint_interval,
            device=args.device,
        )
    prov = run.provenance
    print(f"run: {run.path}")
    print(
        f"final return {run.final_return:.2f}; wall {prov['wall_time_s']:.1f} s; "
        f"{prov['env_steps_per_s']} env steps/s on {prov['device']}"
    )
    return 0


def _train_seeds(specs: list[Any], args: argparse.Namespace) -> int:
    """Several seeds through the grid path: seed batches, worker processes, checkpoints."""
    from replicate.errors import HarnessError
    from replicate.grids.experiments import GridOptions, run_grid

    options = GridOptions(
        workers=args.workers,
        checkpoint_interval=args.checkpoint_interval,
        device=args.device,
        batch=args.batch,
    )
    outcome = run_grid(specs, args.store, options)
    for run in sorted(outcome.runs, key=lambda r: r.spec["seed"]):
        print(f"run: {run.path}  final return {run.final_return:.2f}")
    if outcome.failed:
        run_id, reason = outcome.failed[0]
        raise HarnessError(
            f"{len(outcome.failed)} of {len(specs)} run(s) failed, e.g. {run_id}: {reason}",
            "fix the cause and run the same command: finished seeds are kept",
        )
    return 0


def _cmd_demos(args: argparse.Namespace) -> int:
    from envs import ENV_SPECS
    from replicate.demos import RULE_EXPERTS, default_demo_path, save_demos
    from replicate.errors import HarnessError
    from replicate.experts import expert_path, make_demos

    if args.all and args.out:
        raise HarnessError(
            "--out names one file; it cannot go with --all",
            "drop --out (each env gets its committed path) or pass --env",
        )
    if args.all:
        env_ids = [e for e in ENV_SPECS if e in RULE_EXPERTS or expert_path(e).is_file()]
        skipped = [e for e in ENV_SPECS if e not in env_ids]
        if skipped:
            print(f"no expert yet (train with `nox -s experts`), skipped: {', '.join(skipped)}")
    else:
        env_ids = [args.env]
    for env_id in env_ids:
        demos = make_demos(env_id, n_pairs=args.pairs, seed=args.seed)
        path = save_demos(args.out or default_demo_path(env_id), demos)
        meta = demos.metadata
        print(
            f"wrote {path}: {meta['n_pairs']} pairs, expert return "
            f"{meta['expert_return_mean']:.2f} +- {meta['expert_return_std']:.2f} over "
            f"{meta['expert_episodes']} episodes, sha256 {meta['content_sha256'][:12]}"
        )
    return 0


def _cmd_expert(args: argparse.Namespace) -> int:
    from replicate.errors import HarnessError
    from replicate.experts import EXPERT_ENVS

    if args.minutes is not None and args.minutes <= 0:
        raise HarnessError(f"--minutes must be positive, got {args.minutes}", "pass --minutes 8")
    for env_id in [args.env] if args.env else EXPERT_ENVS:
        _one_expert(argparse.Namespace(**{**vars(args), "env": env_id}))
    return 0


def _one_expert(args: argparse.Namespace) -> None:
    import torch
    from tqdm import tqdm

    from replicate.experts import export_expert, train_expert

    if args.export_only:
        path = export_expert(args.env, args.root)
    else:
        seeds = args.seeds if args.seeds is not None else [args.seed]
        with tqdm(
            total=args.steps * len(seeds),
            unit="step",
            desc=f"expert {args.env}",
            dynamic_ncols=True,
            mininterval=2.0,
        ) as bar:
            path = train_expert(
                args.env,
                args.steps,
                seeds,
                args.root,
                eval_interval=args.eval_interval,
                checkpoint_interval=args.checkpoint_interval,
                on_steps=bar.update,
                algo=args.algo,
                threads=args.threads,
                device=args.device,
                time_limit_s=None if args.minutes is None else 60 * args.minutes,
            )
    meta = torch.load(path, weights_only=True)["metadata"]
    print(
        f"expert: {path}: best evaluation {meta['best_eval_return']:.1f} at step "
        f"{meta['best_step']:,} of {meta['steps_trained']:,}; wall {meta['wall_time_s']:.0f} s"
    )


def _cmd_carry(args: argparse.Namespace) -> int:
    from replicate.errors import HarnessError
    from replicate.store import carry

    if not args.list:
        if args.workers < 1:
            raise HarnessError(
                f"--workers must be at least 1, got {args.workers}", "pass --workers 1 or more"
            )
        packed, skipped = carry.pack_all(args.store, progress=True, workers=args.workers)
        for item in packed:
            print(
                f"carried {item.name}: step {item.step:,}, {item.members} run(s), "
                f"{item.bytes / 2**20:.1f} MiB"
            )
        for line in skipped:
            print(f"not carried: {line}")
        if not packed and not skipped:
            print(f"no unfinished checkpoint in {args.store}")
    for manifest in carry.listing(args.store):
        print(
            f"{carry.carry_root(args.store) / manifest['name']}: {manifest['kind']} at step "
            f"{manifest['step']:,} of {', '.join(manifest['members'])} (packed "
            f"{manifest['packed_utc']} on {manifest['cpu_model']})"
        )
    return 0


def _cmd_algos(args: argparse.Namespace) -> int:
    import dataclasses

    from baselines.registry import algorithms

    for name, algo in sorted(algorithms().items()):
        notes = [
            note
            for note, applies in (("uses demonstrations", algo.needs_demos), ("GPU path", algo.gpu))
            if applies
        ]
        suffix = f" ({', '.join(notes)})" if notes else ""
        print(f"{name}: {algo.summary}{suffix}")
        for f in dataclasses.fields(algo.config_cls):
            print(f"    {f.name} = {f.default!r}")
    return 0


def _cmd_envs(args: argparse.Namespace) -> int:
    from envs import ENV_SPECS

    print(f"{'env id':42} {'obs':>4} {'act':>4} {'limit':>6}  reward  paper")
    for s in ENV_SPECS.values():
        paper = f"{s.paper_env_id} ({s.paper_obs_dim}/{s.paper_act_dim})" if s.paper_env_id else "-"
        print(
            f"{s.env_id:42} {s.obs_dim:>4} {s.act_dim:>4} {s.max_episode_steps:>6}  "
            f"{s.reward_kind:6}  {paper}"
        )
    return 0


TRAIN = Command("train", _declare_train, _cmd_train)
DEMOS = Command("demos", _declare_demos, _cmd_demos)
EXPERT = Command("expert", _declare_expert, _cmd_expert)
CARRY = Command("carry", _declare_carry, _cmd_carry)
ALGOS = Command("algos", _declare_algos, _cmd_algos)
ENVS = Command("envs", _declare_envs, _cmd_envs)
