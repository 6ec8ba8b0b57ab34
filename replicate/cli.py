"""Command line: ``python -m replicate COMMAND ...`` (``--help`` lists the commands)."""

from __future__ import annotations

import argparse
import ast
import os
import re
import shlex
import sys
import time
from collections.abc import Callable
from pathlib import Path

from replicate.profiles import PROFILES

# The committed run store; smoke-profile runs (numbers that mean nothing) go to their own.
DEFAULT_STORE = Path("runs")
SMOKE_STORE = Path("runs-smoke")
PROFILE_NAMES = tuple(PROFILES)
STORE_HELP = (
    "run store directory (default: $REPLICATE_STORE, else runs/, the committed "
    "store, or runs-smoke/ for the smoke profile)"
)
# Exit status of a command stopped at its --time-limit (sysexits' EX_TEMPFAIL: try again),
# so that a job script can tell "resume me" from success and from failure.
TIME_LIMIT_EXIT = 75


class _HelpFormatter(argparse.HelpFormatter):
    """States an option's default once: appended only where its help does not already say
    it and there is one to state (ArgumentDefaultsHelpFormatter appends "(default: None)"
    even after a help that names its own default)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (
            "default" in text.lower()
            or not action.option_strings
            or action.default in (None, False, [], argparse.SUPPRESS)
        ):
            return text
        return text + " (default: %(default)s)"


def _profile_help(lead: str = "budget profile") -> str:
    """Every profile with its description, for the --profile options."""
    described = [
        f"{name}: {profile.summary}"
        + ("; its numbers mean nothing." if not profile.meaningful else ".")
        for name, profile in PROFILES.items()
    ]
    return f"{lead}. " + " ".join(described)


_DURATION = re.compile(r"(\d+(?:\.\d*)?|\.\d+)\s*([hms]?)")
_UNIT_SECONDS = {"h": 3600.0, "m": 60.0, "s": 1.0, "": 1.0}


def parse_time_limit(text: str) -> float:
    """``90m``, ``2h``, ``1h30m``, ``45s`` or plain seconds (``5400``) as seconds; anything
    else, zero or negative is refused with the fix."""
    from replicate.errors import HarnessError

    cleaned = text.strip().lower()
    negative = cleaned.startswith("-")
    cleaned = cleaned.removeprefix("-").strip()
    pos, seconds, units = 0, 0.0, []
    while pos < len(cleaned):
        match = _DURATION.match(cleaned, pos)
        if match is None:
            break
        seconds += float(match.group(1)) * _UNIT_SECONDS[match.group(2)]
        pos = match.end()
        units.append(match.group(2))
        while pos < len(cleaned) and cleaned[pos] == " ":
            pos += 1
    # a bare number is seconds only alone: "2h30" might mean minutes
    if not units or pos != len(cleaned) or (len(units) > 1 and "" in units):
        raise HarnessError(
            f"--time-limit: cannot read '{text}' as a duration",
            "write it like 90m, 2h, 1h30m or 5400 (seconds)",
        )
    if negative or seconds <= 0:
        raise HarnessError(
            f"--time-limit must be positive, got '{text}'",
            "pass a duration like 90m or 2h, or leave the option out",
        )
    return seconds


def _joined_time_limit(argv: list[str]) -> list[str]:
    """``--time-limit -5m`` as ``--time-limit=-5m``: argparse takes a value that starts with
    '-' for an option and answers with its usage; joined, the limit's own check says on one
    line what is wrong with it."""
    joined: list[str] = []
    for arg in argv:
        if joined and joined[-1] == "--time-limit" and arg.startswith("-"):
            joined[-1] = f"--time-limit={arg}"
        else:
            joined.append(arg)
    return joined


def _add_time_limit_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--time-limit",
        default=None,
        metavar="DURATION",
        help="stop cleanly after this long (90m, 2h, 1h30m, or seconds): "
        "finished runs are kept, running ones checkpoint at their next "
        "episode end and stop, the rest do not start; the same command "
        f"resumes them. Exit status {TIME_LIMIT_EXIT}; no limit by default",
    )


def default_store(profile: str | None) -> Path:
    if os.environ.get("REPLICATE_STORE"):
        return Path(os.environ["REPLICATE_STORE"])
    return SMOKE_STORE if profile == "smoke" else DEFAULT_STORE


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


DEVICE_HELP = (
    "where algorithms with a GPU path (the SAC family: SAC, twin-Q SAC, DRL-EG, "
    "IBRL, JSRL, RLPD) train: auto takes the GPU when torch sees one; cuda fails "
    "without one. The others train on CPU. Curves are reproducible bit for bit on "
    "CPU only"
)


def _add_device_argument(parser: argparse.ArgumentParser, grid: bool = False) -> None:
    from baselines.registry import batchable_algorithms

    parser.add_argument(
        "--device", default="auto", choices=["auto", "cpu", "cuda"], help=DEVICE_HELP
    )
    if grid:
        parser.add_argument(
            "--gpu-workers",
            type=int,
            default=None,
            help="with --device auto and a GPU: only this many workers train "
            "on it, the others on the CPU cores. One GPU serves about two "
            "runs at once, so 2 is faster on a many-core machine, but "
            "which runs land on the GPU then depends on scheduling "
            "(default: every worker on the GPU)",
        )
        parser.add_argument(
            "--batch",
            type=int,
            default=None,
            metavar="N",
            help="train up to N runs that differ only in seed together in "
            f"one process ({', '.join(batchable_algorithms())}; the others "
            "train one per process). Default: on a GPU as many as fit its "
            "memory (up to 64), on CPU none",
        )


def _add_cell_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--algos",
        nargs="+",
        default=None,
        metavar="ALGO",
        help="train only these algorithms' cells of the grid (the report is "
        "still written from every run of the grid in the store)",
    )
    parser.add_argument(
        "--envs",
        nargs="+",
        default=None,
        metavar="ENV",
        help="train only these environments' cells of the grid",
    )
    parser.add_argument(
        "--dry-run",
        action="store_true",
        help="print the runs that would train, per cell, with their env steps "
        "and estimated minutes; train and write nothing",
    )


CHECKPOINT_HELP = (
    "env steps between checkpoints of each run or seed batch (0: none); an interrupted "
    "command resumes its unfinished runs from them. A batch's holds every member's replay, "
    "so give large batches more"
)
DRY_RUN_HELP = (
    "print the runs that would train, with their env steps and estimated minutes; train "
    "and write nothing"
)


def _add_grid_arguments(
    parser: argparse.ArgumentParser,
    out_help: str,
    profile_default: str = "quick",
    profile_help: str | None = None,
    seeds_help: str | None = "number of seeds (default: the profile's)",
    ray: bool = False,
    cells: bool = False,
) -> None:
    """The options every figure command that trains a grid shares, declared once."""
    parser.add_argument(
        "--profile",
        default=profile_default,
        choices=PROFILE_NAMES,
        help=profile_help or _profile_help(),
    )
    if seeds_help is not None:
        parser.add_argument("--seeds", type=int, default=None, help=seeds_help)
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help="parallel training processes (default: one per core)",
    )
    parser.add_argument("--store", type=Path, default=None, help=STORE_HELP)
    parser.add_argument("--out", type=Path, default=None, help=out_help)
    _add_device_argument(parser, grid=True)
    if ray:
        parser.add_argument(
            "--executor",
            default="local",
            choices=["local", "ray"],
            help="local processes, or tasks on a running Ray cluster (--address)",
        )
        parser.add_argument(
            "--address",
            default=None,
            help="HOST:PORT of the Ray head for --executor ray; the run store must "
            "be on a filesystem every node sees",
        )
    parser.add_argument("--checkpoint-interval", type=int, default=10_000, help=CHECKPOINT_HELP)
    _add_time_limit_argument(parser)
    if cells:
        _add_cell_arguments(parser)
    else:
        parser.add_argument("--dry-run", action="store_true", help=DRY_RUN_HELP)


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m replicate",
        description="Replication harness for DRL-EG (SAC with demonstration-guided exploration).",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    train = sub.add_parser(
        "train",
        help="train one run into the run store",
        description="Train one run (algorithm x env x seed x budget) into the run store, "
        "with a progress bar. A run whose resolved spec is already complete in "
        "the store is not trained again.",
        formatter_class=_HelpFormatter,
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
    _add_device_argument(train)

    demos = sub.add_parser(
        "demos",
        help="make a demonstration file from the harness's own expert",
        description="Roll out the expert of an env and save (s, a) pairs with provenance.",
        formatter_class=_HelpFormatter,
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

    expert = sub.add_parser(
        "expert",
        help="train (or resume) the harness's SAC expert of an env",
        description="Train the SAC expert of an env: one run per seed (several as one seed "
        "batch) in the run store --root/<env>/, checkpointed; started again, it resumes. "
        "The policy with the best evaluation of any of them is exported, with its "
        "provenance, to the package's expert file, from which `demos` rolls out "
        "demonstrations.",
        formatter_class=_HelpFormatter,
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
    _add_device_argument(expert)
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

    fig3 = sub.add_parser(
        "fig3",
        help="train what Fig. 3 needs and write its HTML report",
        description="Run the Fig. 3 grid for a profile (only runs missing from the store are "
        "trained), then write the self-contained HTML report.",
        formatter_class=_HelpFormatter,
    )
    _add_grid_arguments(
        fig3,
        "report directory (default: reports/fig3 for quick, reports/<profile>/fig3 otherwise)",
        ray=True,
        cells=True,
    )

    fig4 = sub.add_parser(
        "fig4",
        help="train what Fig. 4 needs (paired SAC and DRL-EG) and write its report",
        description="Train SAC and DRL-EG on the same seeds (identical initial weights) on "
        "Ant-v5, or --env, and write reports/fig4/index.html: one panel per "
        "seed, paired differences, claim 5.",
        formatter_class=_HelpFormatter,
    )
    _add_grid_arguments(
        fig4,
        "report directory (default: reports/fig4 for quick, reports/<profile>/fig4 otherwise)",
        seeds_help="number of seeds (default 4)",
        ray=True,
    )
    fig4.add_argument("--env", default="Ant-v5", help="environment (the paper's is Ant-v5)")

    ablate = sub.add_parser(
        "ablate-threshold",
        help="sweep DRL-EG's threshold T2 (and sigma) with optuna",
        description="Train DRL-EG over a grid of T2 (and sigma) values, one optuna trial "
        "per point, at the Fig. 3 profile's budget and seeds, and write "
        "reports/ablate-threshold/index.html. Stopped sweeps resume; several "
        "workers can share one --storage.",
        formatter_class=_HelpFormatter,
    )
    _add_grid_arguments(
        ablate,
        "report directory (default: reports/ablate-threshold[-<env>] for quick, under "
        "reports/<profile>/ otherwise)",
        ray=True,
    )
    ablate.add_argument(
        "--thresholds",
        type=float,
        nargs="+",
        default=None,
        help="T2 values (default: the profile's grid, 0 and 'always' included)",
    )
    ablate.add_argument(
        "--sigmas",
        type=float,
        nargs="+",
        default=None,
        help="guider noise values (default: the profile's grid)",
    )
    ablate.add_argument(
        "--storage", default=None, help="optuna storage URL (default: SQLite in the run store)"
    )
    ablate.add_argument(
        "--env",
        default="MountainCarContinuous-v0",
        help="the env to sweep: MountainCar (absolute T2 grid), or Ant-v5 or "
        "Walker2d-v5 (T2 at 1, 4, 16, 64 times the median demonstration-"
        "state spacing, and always; 3 seeds)",
    )

    rlfd = sub.add_parser(
        "compare-rlfd",
        help="DRL-EG against IBRL, RLPD, JSRL, SAC and DDPGfD: reports/rlfd",
        description="Train the comparison grid (only runs missing from the store) on the "
        "profile's tasks and write reports/rlfd/index.html: normalised scores, IQM, "
        "probability of improvement, performance profiles, sample-efficiency "
        "curves and a verdict per method and task.",
        formatter_class=_HelpFormatter,
    )
    _add_grid_arguments(
        rlfd,
        "report directory (default: reports/rlfd for quick, reports/<profile>/rlfd otherwise)",
        profile_help=_profile_help(
            "budget profile (here quick is MountainCar; reduced "
            "adds the sparse dm-control tasks, Hopper and Ant)"
        ),
        seeds_help="number of seeds (default 5)",
        cells=True,
    )

    start = sub.add_parser(
        "random-start",
        help="SAC with the SAC authors' random start against today's start",
        description="Train SAC on HalfCheetah-v5 and Ant-v5 with 10,000 uniform-random "
        "start steps, from the seeds of the profile's Fig. 3 SAC runs (only runs missing "
        "from the store), and write reports/<profile>/random-start/index.html: each env's "
        "paired difference in final return and area under the curve.",
        formatter_class=_HelpFormatter,
    )
    _add_grid_arguments(
        start,
        "report directory (default: reports/<profile>/random-start)",
        profile_default="reduced",
        seeds_help=None,
    )

    report = sub.add_parser(
        "report",
        help="rebuild reports from the run store without training",
        description="Rebuild every report of a profile (Fig. 3, Fig. 4, the threshold "
        "ablation, Table 1) from the runs already in the store; nothing is trained. "
        "Fig. 3 lists its missing runs; Fig. 4 and the ablation are left as they "
        "are when the store holds none of their runs.",
        formatter_class=_HelpFormatter,
    )
    report.add_argument(
        "--profile",
        default=None,
        choices=PROFILE_NAMES,
        help=_profile_help(
            "which profile's reports to rebuild (default: "
            "every profile but smoke whose runs are in the "
            "store)"
        ),
    )
    report.add_argument(
        "--seeds", type=int, default=None, help="number of seeds (default: the profile's)"
    )
    report.add_argument("--store", type=Path, default=None, help=STORE_HELP)
    report.add_argument(
        "--out",
        type=Path,
        default=None,
        help="parent directory of the reports (default: reports/ for quick, "
        "reports/<profile>/ otherwise; with several profiles, "
        "<out>/<profile>/<name>)",
    )

    table1 = sub.add_parser(
        "table1",
        help="write Table 1 (env dims, paper beside harness, demonstrations)",
        description="Write reports/table1/index.html from the environment table, checked "
        "against the live envs, and the committed demonstration files.",
        formatter_class=_HelpFormatter,
    )
    table1.add_argument("--out", type=Path, default=Path("reports/table1"), help="report directory")

    carry = sub.add_parser(
        "carry",
        help="pack the store's unfinished runs and batches small enough to commit",
        description="Pack every checkpoint of the store's unfinished runs and seed batches "
        "into <store>/carry/ without its replay buffer (rebuilt from the actions "
        "when unpacked, and checked against its SHA-256), so that it can be "
        "committed and resumed by the same command later, on this machine or "
        "another. Training may go on while it packs.",
        formatter_class=_HelpFormatter,
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

    sub.add_parser("algos", help="list algorithms and their default hyperparameters")
    sub.add_parser("envs", help="list environments and their spec table")
    return parser


def _cmd_train(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from replicate.runner import execute, prepare
    from replicate.spec import RunSpec

    eval_interval = args.eval_interval or max(1, args.steps // 20)
    spec = RunSpec(
        algo=args.algo,
        env_id=args.env,
        seed=args.seed,
        total_steps=args.steps,
        eval_interval=eval_interval,
        eval_episodes=args.eval_episodes,
        hyperparameters=_parse_overrides(args.overrides),
        demos=args.demos,
    )
    prepared = prepare(spec)
    with tqdm(
        total=spec.total_steps, unit="step", desc=prepared.run_id[:48], dynamic_ncols=True
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


def _cmd_demos(args: argparse.Namespace) -> int:
    from envs import ENV_SPECS
    from replicate.demos import RULE_EXPERTS, default_demo_path, make_demos, save_demos
    from replicate.errors import HarnessError
    from replicate.experts import expert_path

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


def _cmd_fig3(args: argparse.Namespace) -> int:
    from replicate.fig3 import run_figure3

    out = args.out or _default_out(args.profile)
    report = run_figure3(
        profile=args.profile,
        seeds=args.seeds,
        store=args.store,
        out_dir=out,
        workers=args.workers,
        checkpoint_interval=args.checkpoint_interval,
        executor=args.executor,
        address=args.address,
        device=args.device,
        gpu_workers=args.gpu_workers,
        batch=args.batch,
        algos=args.algos,
        envs=args.envs,
        dry_run=args.dry_run,
    )
    if report is not None:
        print(f"report: {report}")
    return 0


def _default_out(profile: str) -> Path:
    from replicate.profiles import report_dir

    return report_dir(profile, "fig3")


def _cmd_fig4(args: argparse.Namespace) -> int:
    from replicate.fig4 import run_figure4

    report = run_figure4(
        profile=args.profile,
        env_id=args.env,
        seeds=args.seeds,
        store=args.store,
        out_dir=args.out,
        workers=args.workers,
        executor=args.executor,
        address=args.address,
        device=args.device,
        gpu_workers=args.gpu_workers,
        batch=args.batch,
        checkpoint_interval=args.checkpoint_interval,
        dry_run=args.dry_run,
    )
    if report is not None:
        print(f"report: {report}")
    return 0


def _cmd_ablate(args: argparse.Namespace) -> int:
    from replicate.ablation import run_threshold_ablation

    report = run_threshold_ablation(
        profile=args.profile,
        seeds=args.seeds,
        store=args.store,
        out_dir=args.out,
        storage=args.storage,
        workers=args.workers,
        thresholds=args.thresholds,
        sigmas=args.sigmas,
        executor=args.executor,
        address=args.address,
        device=args.device,
        gpu_workers=args.gpu_workers,
        batch=args.batch,
        env_id=args.env,
        checkpoint_interval=args.checkpoint_interval,
        dry_run=args.dry_run,
    )
    if report is not None:
        print(f"report: {report}")
    return 0


def _cmd_rlfd(args: argparse.Namespace) -> int:
    from replicate.rlfd import run_rlfd

    report = run_rlfd(
        profile=args.profile,
        seeds=args.seeds,
        store=args.store,
        out_dir=args.out,
        workers=args.workers,
        checkpoint_interval=args.checkpoint_interval,
        device=args.device,
        batch=args.batch,
        algos=args.algos,
        envs=args.envs,
        dry_run=args.dry_run,
    )
    if report is not None:
        print(f"report: {report}")
    return 0


def _cmd_random_start(args: argparse.Namespace) -> int:
    from replicate.random_start import run_random_start

    report = run_random_start(
        profile=args.profile,
        store=args.store,
        out_dir=args.out,
        dry_run=args.dry_run,
        workers=args.workers,
        checkpoint_interval=args.checkpoint_interval,
        device=args.device,
        batch=args.batch,
    )
    if report is not None:
        print(f"report: {report}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from replicate.figure_registry import figures
    from replicate.profiles import report_dir
    from replicate.report import write_unless_fewer
    from replicate.table1 import write_table1_report

    profiles = [args.profile] if args.profile else [p for p in PROFILE_NAMES if p != "smoke"]

    def target(profile: str, name: str) -> Path | None:
        """Where to write; None to leave out: without --profile, only the default profile's
        reports and those already written (committed) are rebuilt, since profiles share runs
        (reduced's MountainCar runs are quick's) and would otherwise each get a report."""
        if args.out is not None:
            return args.out / profile / name if len(profiles) > 1 else args.out / name
        path = report_dir(profile, name)
        keep = args.profile or profile == "quick" or (path / "summary.json").is_file()
        return path if keep else None

    def rebuild(profile: str, name: str, build: Callable[[Path], Path | None]) -> str:
        path = target(profile, name)
        if path is None:
            not_written.add(profile)
            return ""
        written, note = write_unless_fewer(path, args.store, build)
        if written is None:
            return note or (
                f"{path}: no runs of the {profile} profile in {args.store}; left as it is"
            )
        return f"report: {written}" + (f" ({note})" if note else "")

    not_written: set[str] = set()

    def report_line(line: str) -> None:
        if line:
            print(line)

    for profile in profiles:
        for name, figure in figures().items():
            report_line(
                rebuild(
                    profile, name, lambda out: figure.rebuild(profile, args.store, out, args.seeds)
                )
            )
    if not_written:
        names = " or ".join(sorted(not_written))
        print(
            f"reports of the {names} profile that were never written are left out "
            f"(they would share the quick profile's runs); pass --profile to write them"
        )
    table1 = write_table1_report(args.out / "table1" if args.out else Path("reports/table1"))
    print(f"report: {table1}")
    from replicate.frontdoor import write_front_door

    print(f"front door: {write_front_door(args.out or Path('reports'))}")
    return 0


def _cmd_table1(args: argparse.Namespace) -> int:
    from replicate.table1 import write_table1_report

    print(f"report: {write_table1_report(args.out)}")
    return 0


def _cmd_carry(args: argparse.Namespace) -> int:
    from replicate import carry
    from replicate.errors import HarnessError

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


COMMANDS = {
    "random-start": _cmd_random_start,
    "compare-rlfd": _cmd_rlfd,
    "train": _cmd_train,
    "demos": _cmd_demos,
    "expert": _cmd_expert,
    "fig3": _cmd_fig3,
    "fig4": _cmd_fig4,
    "report": _cmd_report,
    "table1": _cmd_table1,
    "ablate-threshold": _cmd_ablate,
    "algos": _cmd_algos,
    "envs": _cmd_envs,
    "carry": _cmd_carry,
}


FIGURE_COMMANDS = ("fig3", "fig4", "ablate-threshold", "compare-rlfd", "table1", "random-start")


def _refreshing_front_door(args: argparse.Namespace, code: int) -> int:
    """After a figure command wrote into reports/ (no --out, a profile that means
    something), refresh the front door reports/index.html from the reports there."""
    if (
        code == 0
        and not getattr(args, "dry_run", False)  # a dry run writes nothing
        and args.command in FIGURE_COMMANDS
        and getattr(args, "out", None) is None
        and getattr(args, "profile", "quick") != "smoke"
        and Path("reports").is_dir()
    ):
        from replicate.frontdoor import write_front_door

        print(f"front door: {write_front_door(Path('reports'))}")
    return code


def main(argv: list[str] | None = None) -> int:
    from replicate.errors import HarnessError, TimeLimitStop

    argv = _joined_time_limit(sys.argv[1:] if argv is None else list(argv))
    args = _build_parser().parse_args(argv)
    if getattr(args, "store", "absent") is None:
        args.store = default_store(getattr(args, "profile", None))
    try:
        if getattr(args, "time_limit", None) is None:
            return _refreshing_front_door(args, COMMANDS[args.command](args))
        limit = parse_time_limit(args.time_limit)  # before anything is trained
        from replicate.experiments import time_limit

        with time_limit(time.time() + limit):
            return _refreshing_front_door(args, COMMANDS[args.command](args))
    except TimeLimitStop as stop:
        print(
            f"time limit reached ({args.time_limit}): {stop}; run the same command again "
            f"to resume: {shlex.join(['python', '-m', 'replicate', *argv])}",
            file=sys.stderr,
        )
        return TIME_LIMIT_EXIT
    except HarnessError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            "interrupted: complete runs are kept in the store; run the same command again "
            "to finish the rest",
            file=sys.stderr,
        )
        return 130


if __name__ == "__main__":
    sys.exit(main())
