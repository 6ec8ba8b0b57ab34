import os
import warnings

os.environ.setdefault("MUJOCO_GL", "disable")
# every training in the suite fails if it draws from a global random generator
# (baselines/contract.py); the subprocesses it starts inherit the rule
os.environ.setdefault("BASELINES_STRICT_RANDOMNESS", "1")
warnings.filterwarnings("ignore", message=".*is different from the unwrapped version.*")

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def smoke_fig3(tmp_path_factory):
    """The smoke profile's Fig. 3, trained once per session: (store, report directory)."""
    from replicate.cli.main import main

    root = tmp_path_factory.mktemp("smoke_fig3")
    store, out = root / "runs", root / "report"
    assert main(["fig3", "--profile", "smoke", "--store", str(store), "--out", str(out)]) == 0
    return store, out
