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
    """The test suite (smoke budgets only; a few minutes on 2 cores)."""
    _install(session, "test")
    session.run("pytest", "-q", *session.posargs, env={"MUJOCO_GL": "disable"})


@nox.session(name="replicate-fig3", python=PYTHON)
def replicate_fig3(session: nox.Session) -> None:
    """Train the Fig. 3 grid (only what the run store lacks) and write reports/fig3/index.html."""
    _install(session)
    session.run("python", "-m", "replicate", "fig3", *session.posargs,
                env={"MUJOCO_GL": "disable"})


@nox.session(python=PYTHON)
def demos(session: nox.Session) -> None:
    """Regenerate the committed demonstrations (MountainCar's rule expert for now)."""
    _install(session)
    session.run("python", "-m", "replicate", "demos", "--env", "MountainCarContinuous-v0",
                *session.posargs)
