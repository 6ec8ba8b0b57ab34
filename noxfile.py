"""Sessions: tests, replicate-fig3, report-free helpers. Run ``nox -l`` to list them.

Arguments after ``--`` go to the command behind the session, e.g.
``nox -s replicate-fig3 -- --profile smoke --seeds 2``.
"""

from __future__ import annotations

import nox

nox.options.sessions = ["tests"]
nox.options.reuse_existing_virtualenvs = True  # installs (torch above all) are paid once
nox.options.default_venv_backend = "venv"

PYTHON = "3.11"


def _install(session: nox.Session, *extras: str) -> None:
    target = f".[{','.join(extras)}]" if extras else "."
    session.install("-e", target)


@nox.session(python=PYTHON)
def tests(session: nox.Session) -> None:
    """The test suite (smoke budgets only; about 10 minutes on 2 cores)."""
    _install(session, "test")
    session.run("pytest", "-q", *session.posargs, env={"MUJOCO_GL": "disable"})


@nox.session(python=PYTHON)
def lint(session: nox.Session) -> None:
    """ruff: lint and format check, as configured in pyproject.toml (CI runs it)."""
    session.install("ruff==0.17.6")  # pinned: another version may format differently
    session.run("ruff", "check", ".")
    session.run("ruff", "format", "--check", ".")


@nox.session(name="replicate-fig3", python=PYTHON)
def replicate_fig3(session: nox.Session) -> None:
    """Train the Fig. 3 grid (only what the run store lacks) and write reports/fig3/index.html."""
    _install(session)
    session.run("python", "-m", "replicate", "fig3", *session.posargs, env={"MUJOCO_GL": "disable"})


@nox.session(name="replicate-fig4", python=PYTHON)
def replicate_fig4(session: nox.Session) -> None:
    """Paired SAC and DRL-EG runs on Ant (same seeds, same initial weights): reports/fig4."""
    _install(session)
    session.run("python", "-m", "replicate", "fig4", *session.posargs, env={"MUJOCO_GL": "disable"})


@nox.session(name="ablate-threshold", python=PYTHON)
def ablate_threshold(session: nox.Session) -> None:
    """Sweep DRL-EG's T2 (and sigma) with optuna; write reports/ablate-threshold/index.html."""
    _install(session)
    session.run(
        "python",
        "-m",
        "replicate",
        "ablate-threshold",
        *session.posargs,
        env={"MUJOCO_GL": "disable"},
    )


@nox.session(name="compare-rlfd", python=PYTHON)
def compare_rlfd(session: nox.Session) -> None:
    """DRL-EG against IBRL, RLPD, JSRL, SAC and DDPGfD on shared demonstrations: reports/rlfd."""
    _install(session)
    session.run(
        "python", "-m", "replicate", "compare-rlfd", *session.posargs, env={"MUJOCO_GL": "disable"}
    )


@nox.session(name="sac-random-start", python=PYTHON)
def sac_random_start(session: nox.Session) -> None:
    """SAC with the SAC authors' random start against the default start (default profile:
    reduced): reports/<profile>/random-start."""
    _install(session)
    session.run(
        "python", "-m", "replicate", "random-start", *session.posargs, env={"MUJOCO_GL": "disable"}
    )


@nox.session(python=PYTHON)
def confirm(session: nox.Session) -> None:
    """Confirmatory plans for the open checks of the claims (default profile: reduced), by
    cost; `-- --check ID` writes one to plans/, `-- --check ID --train` trains it once
    committed, `-- --status` judges the registered ones."""
    _install(session)
    session.run(
        "python", "-m", "replicate", "confirm", *session.posargs, env={"MUJOCO_GL": "disable"}
    )


@nox.session(python=PYTHON)
def bench(session: nox.Session) -> None:
    """Throughput against Stable-Baselines3 and the update floor, seed batches, the compiled
    gradient step; reports/bench/*.json (docs/performance.md)."""
    _install(session)
    session.install("stable-baselines3==2.9.2")  # the reference, a bench-only dependency
    session.install("pytest", "pytest-benchmark")
    env = {"MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1"}
    session.run("python", "benchmarks/bench.py", *session.posargs, env=env)
    # one CPU gradient step: where its time goes, and torch.compile against eager (into
    # bench.json beside the above)
    session.run("python", "benchmarks/cpu_step.py", env=env)
    # the seed-batched trainer: CPU sections (SAC; IBRL and RLPD) here
    cpu_out = "reports/bench/batched_cpu.json"  # the file docs/performance.md reads
    session.run("python", "benchmarks/batched.py", "--cpu", "--rlfd-cpu", "--out", cpu_out, env=env)
    # the trainer's stacked networks against torch.vmap over ordinary modules, one V-SAC step
    session.run("python", "benchmarks/stacked_vs_vmap.py", env=env)
    # the GPU section, where torch sees a GPU
    probe = "import torch; print(torch.cuda.is_available())"
    if str(session.run("python", "-c", probe, silent=True, env=env)).strip().endswith("True"):
        gpu_out = "reports/bench/batched_gpu.json"  # beside the CPU sections' file, not over it
        session.run("python", "benchmarks/batched.py", "--gpu", "--out", gpu_out, env=env)
    # micro-benchmarks, saved so that two commits compare (pytest-benchmark compare)
    session.run(
        "pytest",
        "-q",
        "-p",
        "no:cacheprovider",
        "benchmarks/test_micro.py",
        "--benchmark-json",
        "reports/bench/micro.json",
        env=env,
    )


@nox.session(name="replicate-table1", python=PYTHON)
def replicate_table1(session: nox.Session) -> None:
    """Write reports/table1/index.html: env dims (paper beside harness) and demonstrations."""
    _install(session)
    session.run(
        "python", "-m", "replicate", "table1", *session.posargs, env={"MUJOCO_GL": "disable"}
    )


@nox.session(python=PYTHON)
def report(session: nox.Session) -> None:
    """Rebuild every report from the run store alone (nothing is trained)."""
    _install(session)
    session.run(
        "python", "-m", "replicate", "report", *session.posargs, env={"MUJOCO_GL": "disable"}
    )


@nox.session(python=PYTHON)
def carry(session: nox.Session) -> None:
    """Pack the store's unfinished runs and seed batches into runs/carry/ to commit them."""
    _install(session)
    session.run(
        "python", "-m", "replicate", "carry", *session.posargs, env={"MUJOCO_GL": "disable"}
    )


@nox.session(python=PYTHON)
def experts(session: nox.Session) -> None:
    """Train (or resume) the SAC experts, every env's in turn (replicate/experts.py lists
    them); `-- --env Hopper-v5 --steps 1000000` for one."""
    _install(session)
    session.run(
        "python", "-m", "replicate", "expert", *session.posargs, env={"MUJOCO_GL": "disable"}
    )


@nox.session(python=PYTHON)
def demos(session: nox.Session) -> None:
    """Regenerate the committed demonstrations of every env that has an expert."""
    _install(session)
    args = session.posargs or ["--all"]
    session.run("python", "-m", "replicate", "demos", *args, env={"MUJOCO_GL": "disable"})
