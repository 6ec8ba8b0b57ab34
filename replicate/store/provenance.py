"""Where a number came from: package versions, git revision, machine."""

from __future__ import annotations

import functools
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

PACKAGES = (
    "torch",
    "numpy",
    "scipy",
    "gymnasium",
    "mujoco",
    "dm-control",
    "shimmy",
    "scikit-learn",
    "pandas",
    "seaborn",
    "matplotlib",
    "jinja2",
    "drl-eg-replicate",
)


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def git_revision() -> str:
    """The commit of the code that ran (``revision_at`` the package's checkout, else the
    working directory's), "unknown" outside git."""
    for where in (Path(__file__).resolve().parent, Path.cwd()):
        try:
            return revision_at(where)
        except (OSError, subprocess.SubprocessError):
            continue
    return "unknown"


TRAINING_CODE = ("envs", "baselines", "replicate", "pyproject.toml")


def revision_at(where: Path) -> str:
    """The commit checked out at ``where``, with '+dirty' when tracked files of the code a
    run executes changed (the packages and pyproject.toml; not docs, tests, the run store or
    the reports)."""
    rev = subprocess.run(
        ["git", "-C", str(where), "rev-parse", "HEAD"],
        capture_output=True,
        text=True,
        timeout=10,
        check=True,
    ).stdout.strip()
    dirty = subprocess.run(
        [
            "git",
            "-C",
            str(where),
            "status",
            "--porcelain",
            "--untracked-files=no",
            "--",
            *(f":(top){path}" for path in TRAINING_CODE),
        ],
        capture_output=True,
        text=True,
        timeout=10,
        check=True,
    ).stdout.strip()
    return rev + ("+dirty" if dirty else "")


@functools.cache
def code_revision() -> str:
    """``git_revision()`` as it was when this process first asked: the runner asks when it
    is imported, so a commit made while a run trains does not relabel the run's code."""
    return git_revision()


PROJECT_ROOT = Path(__file__).resolve().parents[2]


def portable_path(path: Path | str, resolve: bool = True) -> str:
    """``path`` relative to the project's root when it lies inside it (a committed run names
    no directory of the machine that trained it), else as given."""
    path = Path(path).resolve() if resolve else Path(path).absolute()
    try:
        return path.relative_to(PROJECT_ROOT).as_posix()
    except ValueError:
        return str(path)


def cpu_model() -> str:
    """The CPU's model name: CPU curves are bit-reproducible on the same kind of CPU only (the
    matrix kernels torch picks, and so their rounding, follow its instruction set)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _can_flush_denormals() -> bool:
    from baselines.common.device import can_flush_denormals  # torch, only when asked

    return can_flush_denormals()


def machine() -> dict[str, str | int]:
    # the interpreter by its venv path inside the project (not resolved: a venv's python is
    # a link to the system's), by its name alone outside it
    executable = portable_path(sys.executable, resolve=False)
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count() or 0,
        "flushes_denormals": _can_flush_denormals(),
        "python_executable": executable
        if not Path(executable).is_absolute()
        else Path(executable).name,
    }
