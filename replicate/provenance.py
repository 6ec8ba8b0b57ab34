"""Where a number came from: package versions, git revision, machine."""

from __future__ import annotations

import functools
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

PACKAGES = ("torch", "numpy", "scipy", "gymnasium", "mujoco", "dm-control", "shimmy",
            "scikit-learn", "pandas", "seaborn", "matplotlib", "jinja2", "drl-eg-replicate")


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def git_revision() -> str:
    """The commit of the code that ran, with '+dirty' when the tree had uncommitted changes."""
    here = Path(__file__).resolve().parent
    for where in (here, Path.cwd()):
        try:
            rev = subprocess.run(["git", "-C", str(where), "rev-parse", "HEAD"],
                                 capture_output=True, text=True, timeout=10, check=True).stdout.strip()
            dirty = subprocess.run(["git", "-C", str(where), "status", "--porcelain",
                                    "--untracked-files=no"],
                                   capture_output=True, text=True, timeout=10).stdout.strip()
            return rev + ("+dirty" if dirty else "")
        except (OSError, subprocess.SubprocessError):
            continue
    return "unknown"


@functools.cache
def code_revision() -> str:
    """``git_revision()`` as it was when this process first asked: the runner asks when it
    is imported, so a commit made while a run trains does not relabel the run's code."""
    return git_revision()


def machine() -> dict[str, str | int]:
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count() or 0, "python_executable": sys.executable}
